"""Human-facing views of results: terminal tables (rich) and the self-contained HTML page (``html``: its inputs
found in ``inputs``, what the sections share loaded in ``context``, the sections as data in ``sections`` and
``traffic_sections`` (blocks of ``blocks``, matplotlib ``figures``), rendered by the Jinja2 templates of
``templates/`` in ``render``). Nothing below this layer imports it."""
