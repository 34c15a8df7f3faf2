"""The motion queue as the command service sees it: which accepted motions are not finished.

The planner owns the real queue; this is its bookkeeping on the command side,
kept from two sources: the motions the planner accepted (``add``) and its
``PlannerProgress`` messages. Motions finish strictly in queue order, so
everything up to ``lastDone`` is done and everything up to ``lastDiscarded`` is
gone. A progress message may be older than the last acceptance (a reply and a
publication travel separately), so an id is dropped only when the message
proves it finished: it is at most ``lastDone``/``lastDiscarded``, or the message
lists later ids but not this one. Ids listed by the planner that the command
does not know (a plan reply that came after its timeout) are adopted, so that
they count against the capacity.
"""

from __future__ import annotations

from jara_arm.schema.planner import PlannerProgress

#: Default capacity [motions] (DECISIONS.md "Motion commands").
DEFAULT_CAPACITY = 32


class MotionQueue:
    """Motion ids accepted and not finished, oldest first; not thread-safe (the caller locks)."""

    def __init__(self, capacity: int = DEFAULT_CAPACITY) -> None:
        if capacity < 1:
            raise ValueError(f"queue capacity must be at least 1, got {capacity}")
        self.capacity = capacity
        self._ids: list[int] = []
        self._last_id = 0  # highest id allocated here or seen from the planner
        self._gone_upto = 0  # every id up to this one is done or discarded

    def __len__(self) -> int:
        return len(self._ids)

    @property
    def ids(self) -> tuple[int, ...]:
        return tuple(self._ids)

    @property
    def full(self) -> bool:
        return len(self._ids) >= self.capacity

    def allocate(self) -> int:
        """A new motion id, above every id used so far (also by a previous command process)."""
        self._last_id += 1
        return self._last_id

    def add(self, motion: int) -> None:
        """The planner accepted ``motion``."""
        if motion > self._gone_upto and motion not in self._ids:
            self._ids.append(motion)
            self._ids.sort()

    def discard_all(self) -> None:
        """``stop``/``abort`` accepted by the planner: everything allocated so far is gone."""
        self._gone_upto = max(self._gone_upto, self._last_id)
        self._ids.clear()

    def update(self, progress: PlannerProgress) -> None:
        """Apply one progress message (see the module docstring)."""
        listed = set(progress.queued)
        if progress.running:
            listed.add(progress.running)
        self._last_id = max(self._last_id, progress.lastDone, progress.lastDiscarded, *listed, 0)
        self._gone_upto = max(self._gone_upto, progress.lastDone, progress.lastDiscarded)
        newest = max(listed, default=0)
        ids = set(self._ids) | listed
        self._ids = sorted(i for i in ids
                           if i > self._gone_upto and (i in listed or i > newest))

    def forget(self) -> None:
        """The planner is gone: nothing it held will run."""
        self.discard_all()
