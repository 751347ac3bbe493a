"""Video input: decoding frames with true timestamps (:mod:`~trafficgeo.video.reader`) and regions of interest
(:mod:`~trafficgeo.video.roi`)."""
