"""terrain: a log-replay toolkit for the self-supervised terrain roughness estimator.

Reproduces Stavens & Thrun (2006), "A Self-Supervised Terrain Roughness Estimator for
Off-Road Autonomous Driving", as staged pipelines over ROS 2 MCAP logs.
"""

__version__ = "0.1.0"
