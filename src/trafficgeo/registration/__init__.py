"""Orthophoto registration: refine a rough GCP calibration by matching the orthophoto, draped on the surface and
seen through the camera, to a video frame (:mod:`.matching`, :mod:`.refine`), judged by the user's own points
(:mod:`.judge`); :mod:`.run` reads and writes the files of ``trafficgeo refine``."""
