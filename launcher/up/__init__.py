"""The cell on this host: ``jara-arm up``, ``router`` and ``service``.

``services`` is the table of the services of an arm (and ``jara-arm service``, one of them in this
process); ``supervisor`` keeps their processes running; ``router`` and ``gateway`` are the cell bus and
the client gateway; ``up`` runs them all.
"""
