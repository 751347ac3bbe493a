"""Closing the loop with SUMO: observed counts -> SUMO demand (routeSampler) -> simulation -> comparison.

* :mod:`~trafficgeo.simulation.tools` - SUMO programs and python tools from the ``eclipse-sumo`` wheel, headless;
* :mod:`~trafficgeo.simulation.network` - a georeferenced SUMO network from the lane polygons (``sumo-net``);
* :mod:`~trafficgeo.simulation.mapping` - counting line x lane x direction -> the SUMO edge and lane it crosses;
* :mod:`~trafficgeo.simulation.demand` - edge data, candidate routes, routeSampler, vehicle types;
* :mod:`~trafficgeo.simulation.scenario` - ``scenario.sumocfg`` and running SUMO on it;
* :mod:`~trafficgeo.simulation.loop` - the simulation against the observation, and demand -> run -> comparison.
"""
