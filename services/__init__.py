"""The four services of one arm (command, planner, servo, alarm monitor), each its own OS process, and the
framework they share (:mod:`.runtime`)."""
