"""Recordings and plots of the arms' samples.

``jara-arm record`` and ``replay`` (``record``, ``replay``; the MCAP file: ``recording``; their progress
line: ``progress``), and ``jara-arm plot`` (``plot_command``; the feedback and the figures: ``plot``,
``traces``, ``plot_figures``), live or from a recording.
"""
