"""Generate ``operations.py``: every operation of the schema as a typed method of :class:`Operations`.

``python -m jara_arm.client.generate`` rewrites the file; ``--check`` exits 1 if the checked-in file
differs from what the schema says (the test suite runs the same check).
"""

from __future__ import annotations

import argparse
import sys
import textwrap
from pathlib import Path

from jara_arm.schema import wire_types as w
from jara_arm.schema.operations import ALL, Interface, Operation
from jara_arm.schema.wire_types import Member

OUTPUT = Path(__file__).with_name("operations.py")

#: The Python type of each wire type: (as a parameter, as a result).
_PY: dict[int, tuple[str, str]] = {
    id(w.DOUBLE): ("float", "float"),
    id(w.ULONG): ("int", "int"),
    id(w.LONG): ("int", "int"),
    id(w.BOOLEAN): ("bool", "bool"),
    id(w.STRING): ("str", "str"),
    id(w.JOINT_POS): ("Sequence[float]", "tuple[float, ...]"),
    id(w.DOUBLE_SEQ): ("Sequence[float]", "tuple[float, ...]"),
    id(w.HG_MATRIX): ("ArrayLike", "NDArray[np.float64]"),
    id(w.LIMIT_VALUE): ("LimitValue", "LimitValue"),
    id(w.LIMIT_SEQ): ("Sequence[LimitValue]", "tuple[LimitValue, ...]"),
    id(w.ALARM_SEQ): ("Sequence[Alarm]", "tuple[Alarm, ...]"),
    id(w.MANIP_INFO): ("ManipInfo", "ManipInfo"),
    id(w.CAR_POS_WITH_ELBOW): ("CarPosWithElbow", "CarPosWithElbow"),
    id(w.CARTESIAN_SPEED): ("CartesianSpeed", "CartesianSpeed"),
}

_HEADER = '''"""Every operation of the arm as a typed method, by its IDL name (generated: do not edit).

``python -m jara_arm.client.generate`` writes this file from ``jara_arm.schema.operations``. A method
returns the operation's out parameters (None, the one, or a tuple in IDL order) and raises
:class:`~jara_arm.client.errors.Refused` for any RETURN_ID but OK; a motion returns its
:class:`~jara_arm.client.motion.Motion`, after its end with ``wait=True`` (the default).
"""

from __future__ import annotations

import abc
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from jara_arm.schema.operations import OP, Interface
from jara_arm.schema.types import Alarm, CarPosWithElbow, CartesianSpeed, LimitValue, ManipInfo

from .motion import Motion


class Operations(abc.ABC):
    """The operations of ``Common``, ``Middle`` and ``Ext``; :class:`~jara_arm.client.Arm` carries them."""

    @abc.abstractmethod
    def _call(self, interface: Interface, name: str, args: Mapping[str, Any]) -> tuple[Any, ...]:
        """The out parameters of one call, in IDL order; raises for anything but OK."""

    @abc.abstractmethod
    def _move(self, interface: Interface, name: str, args: Mapping[str, Any], wait: bool,
              timeout: float | None) -> Motion:
        """One motion operation: its handle, after its end if ``wait``."""
'''


def _py(member: Member, result: bool) -> str:
    try:
        return _PY[id(member.type)][result]
    except KeyError:
        raise SystemExit(f"client/generate.py: no Python type for {member.type.name} ({member.name}): add it "
                         "to _PY") from None


def _doc(op: Operation) -> str:
    lines = [op.doc if op.interface is not Interface.EXT else op.doc.split(": ", 1)[-1]]
    for m in op.inputs:
        unit = f" [{m.unit}]" if m.unit else ""
        lines.append(f"``{m.name}``{unit}{': ' + m.doc if m.doc else ''}.")
    if op.interface is Interface.EXT:
        lines.append("A model-specific extension (``Ext``), not in the IDL.")
    text = " ".join(lines)
    return "\n".join(textwrap.wrap(f'"""{text}"""', 108, initial_indent=" " * 8, subsequent_indent=" " * 8))


def _method(op: Operation) -> str:
    params = ["self", *(f"{m.name}: {_py(m, False)}" for m in op.inputs)]
    args = "{" + ", ".join(f'"{m.name}": {m.name}' for m in op.inputs) + "}"
    where = f"Interface.{op.interface.name}, OP.{op.name}"
    if op.motion:
        params += ["*", "wait: bool = True", "timeout: float | None = None"]
        returns = "Motion"
        body = [f"return self._move({where}, args, wait, timeout)"]
    else:
        outs = [_py(m, True) for m in op.outputs]
        returns = "None" if not outs else outs[0] if len(outs) == 1 else f"tuple[{', '.join(outs)}]"
        call = f"self._call({where}, args)"
        body = ([call] if not outs else [f"result: {outs[0]} = {call}[0]", "return result"] if len(outs) == 1
                else [f"out = {call}", f"return ({', '.join(f'out[{i}]' for i in range(len(outs)))})"])
    signature = f"    def {op.name}({', '.join(params)}) -> {returns}:"
    if len(signature) > 116:
        signature = f"    def {op.name}(\n" + "".join(f"            {p},\n" for p in params) + f"    ) -> {returns}:"
    lines = [f"args: dict[str, Any] = {args}", *body]
    return f"{signature}\n{_doc(op)}\n" + "".join(f"        {line}\n" for line in lines)


def render() -> str:
    return _HEADER + "".join(f"\n{_method(op)}" for op in ALL) + '\n\n__all__ = ["Operations"]\n'


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="exit 1 if operations.py is not what it would write")
    args = ap.parse_args(argv)
    text = render()
    if args.check:
        if OUTPUT.read_text() != text:
            print(f"{OUTPUT} is out of date: run python -m jara_arm.client.generate", file=sys.stderr)
            return 1
        return 0
    OUTPUT.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
