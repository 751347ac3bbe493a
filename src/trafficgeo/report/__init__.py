"""Human-facing views of results: terminal tables (rich) and the self-contained HTML page (``html``, with its
matplotlib ``figures``). Nothing below this layer imports it."""
