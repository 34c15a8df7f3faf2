"""The alarm monitor service: owns each arm's list of active alarms, detects, reacts, publishes."""
