"""The client tools: commands that join the network as a client and ask or watch the arms.

``call``, ``echo``, ``state`` (``state_view``), ``wait``, ``logs`` and ``alarms`` (``watch``, which
also prints the logs of ``jara-arm up``), ``demo``; and what they share: ``client`` (``ArmClient``, a
typed client of one arm over plain queries) and ``arm_state`` (the state bits by name).
"""
