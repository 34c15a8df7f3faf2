"""Planner service: paths, Ruckig timing, the hand-over of whole motions to the servo (kinematics: jara_arm.kinematics)."""
