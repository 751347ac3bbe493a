"""A run put together: the public stages (:mod:`.stages`: detect, track, analyze) and the entry points that
compose them into a run folder (:mod:`.run`: ``process_video``, ``stitch``)."""
