"""A run's output folder: :class:`~trafficgeo.run.folder.RunFolder` (written in one ``writing`` block, read back
checked against its manifest), the schema of its tables (:mod:`trafficgeo.run.schema`) and its JSON records
(:mod:`trafficgeo.run.records`). Below the video and traffic rooms, which both write into it."""
