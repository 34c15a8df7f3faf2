"""``jara-arm call OP [JSON]``: any operation of an arm by its name (IDL or Ext), its reply printed as JSON.

The operation is looked up in ``schema.operations`` and its parameters are
checked with the codec before anything is sent, so that a typo or a wrong type
is reported here, with the operation's parameter list, and the arm never sees
the request.
"""

from __future__ import annotations

import argparse
import dataclasses
import difflib
import json
import sys
import time
from collections.abc import Mapping
from typing import Any, TextIO

from jara_arm.client import Arm, NoAnswer
from jara_arm.schema import codec
from jara_arm.schema import wire_types as w
from jara_arm.schema.codec import Reply
from jara_arm.schema.codes import ReturnCode
from jara_arm.schema.errors import JaraArmError, WireError
from jara_arm.schema.operations import ALL, COMMON, Operation
from jara_arm.services.runtime.arguments import positive_float
from jara_arm.services.runtime.stop_signals import StopSignals

from ..command import USAGE_ERROR, Command, setup_logging
from ..session import add_arm, add_client_zenoh_arguments, no_answer, open_session

#: Exit status of a reply whose id is not OK, or of no reply at all.
FAILED = 1
_MATCHES = 5  #: close matches offered for an unknown operation name


class CallError(JaraArmError, ValueError):
    """A call that cannot be sent as written: unknown operation, bad parameters (the message says why)."""


@dataclasses.dataclass(frozen=True)
class Call:
    """A checked call: the operation, where it goes and its decoded ``in`` parameters."""

    op: Operation
    servo: bool  # to ``Servo/Common`` (the servo) rather than to the command service
    args: Mapping[str, Any]


def operation_names(servo: bool = False) -> tuple[str, ...]:
    """Every name ``call`` takes: the Common operations, and the Middle and Ext ones unless ``servo``."""
    return tuple(COMMON) if servo else tuple(op.name for op in ALL)


def close_matches(name: str, servo: bool = False) -> list[str]:
    """The operation names closest to ``name`` (case ignored), best first."""
    names = operation_names(servo)
    by_lower = {n.lower(): n for n in names}
    found = difflib.get_close_matches(name.lower(), list(by_lower), n=_MATCHES, cutoff=0.6)
    prefixed = [n for n in names if n.lower().startswith(name.lower()) and n.lower() not in found] if name else []
    return [by_lower[n] for n in found] + prefixed[:max(0, _MATCHES - len(found))]


def find_operation(name: str, servo: bool = False) -> Operation:
    """The operation ``name`` (Common, Middle or Ext; Common only for the servo); CallError with close matches."""
    found = next((op for op in ALL if op.name == name), None)
    if found is not None and (not servo or found.name in COMMON):
        return found
    if servo and found is not None:
        raise CallError(f"the servo serves only the Common operations, not {name!r} ({found.interface.value}): "
                        f"drop --servo, or call one of {', '.join(COMMON)}")
    matches = close_matches(name, servo)
    hint = f"did you mean {', '.join(matches)}?" if matches else \
        f"the operations are: {', '.join(operation_names(servo))}"
    raise CallError(f"no operation {name!r}; {hint}")


def describe_type(t: w.WireType[Any]) -> str:
    """A wire type on one line as a reader needs it; a struct by its name (its members: :func:`member_lines`)."""
    if isinstance(t, w.SeqType):
        return f"{t.name}, a list of {describe_type(t.item)}"
    if isinstance(t, w.HgMatrixType):
        return f"{t.name}, 3 rows of 4 numbers: rotation in columns 0-2, translation [m] in column 3"
    if isinstance(t, w.IntegerType):
        return f"{t.name} ({t.lo} .. {t.hi})"
    if isinstance(t, w.AlarmTypeType):
        return f"{t.name} (one of {', '.join(json.dumps(v) for v in t.json_schema()['enum'])})"
    return t.name


def member_lines(m: w.Member, indent: str = "  ") -> list[str]:
    """``name: type [unit], meaning``, then the members of a struct (or of a list's struct), indented."""
    unit = f" [{m.unit}]" if m.unit else ""
    doc = f", {m.doc}" if m.doc else ""
    lines = [f"{indent}{m.name}: {describe_type(m.type)}{unit}{doc}"]
    inner = m.type.item if isinstance(m.type, w.SeqType) else m.type
    if isinstance(inner, w.StructType):
        for member in inner.members:
            lines += member_lines(member, indent + "  ")
    return lines


def example_value(t: w.WireType[Any]) -> Any:
    """A well-formed wire value of ``t`` (identity for a transform, zeros elsewhere), for the usage line."""
    if isinstance(t, w.StructType):
        return {m.name: example_value(m.type) for m in t.members}
    if isinstance(t, w.SeqType):
        return [example_value(t.item)]
    if isinstance(t, w.HgMatrixType):
        return [[1.0 if i == j else 0.0 for j in range(4)] for i in range(3)]
    if isinstance(t, w.IntegerType):
        return t.lo
    if isinstance(t, w.DoubleType):
        return 0.0
    if isinstance(t, w.BooleanType):
        return False
    if isinstance(t, w.AlarmTypeType):
        return t.json_schema()["enum"][0]
    return ""


def parameter_list(op: Operation, servo: bool = False) -> str:
    """The operation, what it does, its parameters with types and units, and an example call."""
    where = "Servo/Common" if servo else op.interface.value
    lines = [f"{op.name} ({where}): {op.doc}"]
    if not op.inputs:
        lines.append("parameters: none")
        return "\n".join(lines)
    lines.append("parameters:")
    for p in op.inputs:
        lines += member_lines(p)
    example = json.dumps({p.name: example_value(p.type) for p in op.inputs})
    lines.append(f"example: jara-arm call {'--servo ' if servo else ''}{op.name} '{example}'")
    return "\n".join(lines)


def parse_call(name: str, text: str | None, servo: bool = False) -> Call:
    """The call ``name`` with parameters ``text`` (a JSON object; or, for an operation of one
    parameter, that parameter's value alone), checked as the service would check it."""
    op = find_operation(name, servo)
    if text is None or not text.strip():
        value: Any = {}
    else:
        try:
            value = json.loads(text)
        except json.JSONDecodeError as exc:
            raise CallError(f"{op.name}: the parameters are not valid JSON ({exc.msg} at column {exc.colno})\n"
                            f"{parameter_list(op, servo)}") from None
        if len(op.inputs) == 1 and not isinstance(value, dict):
            value = {op.inputs[0].name: value}  # `call setSpeedJoint 50`: the one parameter alone
    try:
        args = codec.decode_args(op, value)
    except WireError as exc:
        raise CallError(f"{op.name}: {exc.field}: {exc.reason}\n{parameter_list(op, servo)}") from None
    return Call(op, servo, args)


def reply_json(op: Operation, reply: Reply) -> dict[str, Any]:
    """The reply in its wire form (what a JSON client receives): ``{id, comment, <out parameters>}``."""
    out: dict[str, Any] = {"id": int(reply.id), "comment": reply.comment}
    for p in op.outputs if reply.ok else ():
        out[p.name] = p.type.encode(reply[p.name])
    return out


def return_code_name(code: int) -> str:
    try:
        return ReturnCode(code).name
    except ValueError:
        return "unknown code"


def run_call(client: Arm, call: Call, out: TextIO, err: TextIO) -> int:
    """Send ``call``, print its reply as JSON on ``out``; 0 if the reply is OK, FAILED otherwise.
    Raises ``NoAnswer`` when nobody answers."""
    reply = client.call(call.op.interface, call.op.name, call.args, servo=call.servo)
    print(json.dumps(reply_json(call.op, reply)), file=out, flush=True)
    if reply.ok:
        return 0
    print(f"jara-arm call: {call.op.name}: {return_code_name(reply.id)} ({reply.id}): {reply.comment}",
          file=err, flush=True)
    return FAILED


def _arguments(parser: argparse.ArgumentParser) -> None:
    add_arm(parser)
    parser.add_argument("--servo", action="store_true",
                        help="ask the servo (Servo/Common/<op>) instead of the command service")
    parser.add_argument("--timeout", type=positive_float, default=10.0, metavar="S",
                        help="wait this long to join the network, and then for the reply [s] (default: 10)")
    parser.add_argument("op", metavar="OP", help="the operation's name (IDL, or Ext), e.g. movePTPJointAbs")
    parser.add_argument("json", nargs="?", metavar="JSON",
                        help="the in parameters as a JSON object (default: none)")
    add_client_zenoh_arguments(parser)


def _run(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    """The call checked first (exit 2, nothing sent), then one session for it."""
    setup_logging("WARNING")
    try:
        call = parse_call(args.op, args.json, args.servo)
    except CallError as exc:
        print(f"{parser.prog}: {exc}", file=sys.stderr)
        return USAGE_ERROR
    began = time.monotonic()
    session = open_session(args, parser, join_within=args.timeout)
    StopSignals()  # SIGINT/SIGTERM noted, not obeyed: the reply is waited for (within --timeout)
    with session:
        # [s] for the reply: what joining left of the timeout
        client = Arm(session, args.arm, timeout=max(0.1, args.timeout - (time.monotonic() - began)))
        try:
            return run_call(client, call, sys.stdout, sys.stderr)
        except NoAnswer as exc:
            return no_answer(args, parser, exc)
        finally:
            client.close()


COMMAND = Command(
    "call", arguments=_arguments, run=_run,
    # the servo serves the Common operations only
    words=operation_names(), option_words={"--servo": operation_names(servo=True)},
    help="call any operation by its name (IDL or Ext) and print the reply as JSON",
    description="Call one of the Common, Middle or Ext operations (Servo/Common with --servo) and "
    "print the reply {id, comment, <out parameters>} as JSON; exit 1 if its id is not OK. "
    "The parameters are checked here first: a mistake is reported with the operation's "
    "parameter list, and nothing is sent.",
    epilog="examples: jara-arm call servoON; jara-arm call setSpeedJoint '{\"spdRatio\": 50}'; "
    "jara-arm call setSpeedJoint 50 (an operation's one parameter may come alone)")
