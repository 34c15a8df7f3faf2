"""The cell on this host: ``jara-arm up`` and ``router``.

``services`` is the table of the services of an arm; ``supervisor`` keeps their processes running;
``router`` and ``gateway`` are the cell bus and the client gateway; ``up`` runs them all.
"""
