"""Forest LiDAR simulator with ground truth: C++ ray casting over an analytic forest (stems,
branches, crowns, shrubs, logs, heightfield), sensor profiles, motion and bag output."""

from forestslam.sim.config import SimConfig
from forestslam.sim.scenarios import available_scenarios, load_scenario
from forestslam.sim.simulate import simulate
from forestslam.sim.stand import Stand, load_stand

__all__ = ["SimConfig", "Stand", "available_scenarios", "load_scenario", "load_stand", "simulate"]
