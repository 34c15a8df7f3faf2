"""The Zenoh entities an object declared, undeclared together when it closes.

Zenoh's publishers, subscribers, queryables and queriers are context managers;
:class:`Entities` is an ``ExitStack`` of them whose :meth:`~Entities.close`
undeclares every one (the last declared first) and never raises: an entity
still in use by a thread that did not stop ("Already borrowed", e.g. a
queryable whose worker sits in ``recv()`` until the session closes) is logged
and left to the session's close, and shutdown goes on.
"""

from __future__ import annotations

import contextlib
import logging

log = logging.getLogger(__name__)

class Entities(contextlib.ExitStack):
    """``enter_context(session.declare_publisher(...))`` at declaration, :meth:`close` at the end."""

    def close(self) -> None:
        """Undeclare every entity (an ``ExitStack`` goes on past a failing one); log, not raise."""
        try:
            super().close()
        except Exception as exc:  # the session's close undeclares what is left
            log.debug("an entity was left to the session's close: %s", exc)
