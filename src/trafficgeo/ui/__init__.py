"""``trafficgeo gcp-ui``: a local web app to pick GCPs between a video frame and an orthophoto and calibrate live.

:mod:`.inputs` loads the frame, the orthophoto and the ground (DEM or lidar); :mod:`.startup` opens a session from
them; :mod:`.session` holds the pairs, their heights, the autosave and the cached live calibration in plain Python;
:mod:`.live` calibrates the pairs into the answer the page draws;
:mod:`.refine` refines that calibration by registering the orthophoto to the frame ("Refine from orthophoto");
:mod:`.overlays` computes the camera footprint and the world grid; :mod:`.server` is the FastAPI app
(``create_app(session)``) and its uvicorn serving; ``static/`` the page (Leaflet 1.9.4 vendored under
``static/vendor/leaflet``, BSD-2-Clause, nothing is fetched from the internet).
"""

from trafficgeo.ui.session import Session, SessionError
from trafficgeo.ui.startup import open_session

__all__ = ["Session", "SessionError", "open_session"]
