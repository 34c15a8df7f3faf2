"""Planner service: paths, Ruckig timing, the position-command stream (kinematics: jara_arm.kinematics)."""
