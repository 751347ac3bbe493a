"""From tracks to traffic data: world trajectories, speeds, lanes, counting lines, SUMO exchange."""
