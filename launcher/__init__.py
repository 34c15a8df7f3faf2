"""``jara-arm``: the launcher (``up``: routers, gateway and the services of every arm), and the client tools
(call, echo, state, wait, logs, alarms, demo, record, replay, plot, view, certs, completion).

Packages by concern: ``up/`` (the cell on this host), ``tools/`` (the client tools), ``record/``
(recordings and plots), ``view/`` (the 3D view), ``secure/`` (a secure cell's certificates). Each command
registers itself next to its code (``command.Command``); ``cli`` is their table, ``completion`` is made
from it; the client commands join the network through ``session``.
"""
