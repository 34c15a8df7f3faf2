"""The client tools: commands that join the network as a client and ask or watch the arms.

``call``, ``echo``, ``state`` (``state_view``), ``wait``, ``logs`` and ``alarms`` (``watch``, which
also prints the logs of ``jara-arm up``), ``demo``; each asks an arm through the public client
(``jara_arm.client.Arm``; ``Arm.call`` where a refusal is shown as it came), and ``arm_state`` gives
the state bits by name.
"""
