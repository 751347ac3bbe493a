"""Many cameras, many files: a manifest of tasks (``batch plan``), run on Dask (``batch run``), written as one
partitioned GeoParquet dataset (``batch summarize``). See :mod:`trafficgeo.batch.model` for the plain data."""
