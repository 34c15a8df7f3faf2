"""The servo service: the PyBullet world, the fixed-period loop, the interpolator that runs, pauses, scales
and stops the buffered motions, the feedback, and the low-level ``Servo/Common`` and ``Servo/posCmd``."""
