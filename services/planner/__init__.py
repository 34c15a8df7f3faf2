"""Planner service: paths, Ruckig timing, Pinocchio kinematics, the position-command stream."""
