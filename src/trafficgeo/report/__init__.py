"""Human-facing views of results (terminal tables now; HTML later). Nothing below this layer imports it."""
