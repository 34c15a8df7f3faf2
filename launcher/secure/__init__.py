"""A secure cell: its certificate authority and identities (``certs``: ``jara-arm certs``), and the
refusals that its routers log (``refusals``)."""
