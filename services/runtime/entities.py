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
from typing import TypeVar

log = logging.getLogger(__name__)

E = TypeVar("E")


class Entities(contextlib.ExitStack):
    """``own(session.declare_publisher(...))`` at declaration, :meth:`close` at the end."""

    def own(self, entity: contextlib.AbstractContextManager[E]) -> E:
        """Declare-side: keep ``entity`` until :meth:`close`, and return it."""
        return self.enter_context(entity)

    def close(self) -> None:
        """Undeclare every entity (an ``ExitStack`` goes on past a failing one); log, not raise."""
        try:
            super().close()
        except Exception as exc:  # the session's close undeclares what is left
            log.debug("an entity was left to the session's close: %s", exc)
