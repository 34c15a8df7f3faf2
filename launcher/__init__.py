"""``jara-arm``: the launcher (``up``: routers, gateway and the services of every arm), and the client tools
(call, echo, state, wait, logs, alarms, demo, record, replay, plot, view, certs, completion)."""
