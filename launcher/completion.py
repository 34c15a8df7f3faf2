"""``jara-arm completion bash``: a bash completion script for the commands, their options, operation
names (``call``), keys (``echo``) and conditions (``wait``).

Generated from the argument parsers and ``schema/``, so that it never lags
behind them: ``source <(jara-arm completion bash)``, or save it under
``/etc/bash_completion.d/``.
"""

from __future__ import annotations

import argparse
import shlex
from collections.abc import Mapping

from jara_arm.schema.keys import KEY_TABLE, PREFIX, Service

from .tools.call import operation_names
from .tools.echo import echo_keys
from .tools.wait import Condition
from .up.services import NAMES

SHELLS = ("bash",)


def echo_words() -> tuple[str, ...]:
    """The keys offered for ``echo``: the key table's, a ``<service>`` chunk spelled out for each service
    (a ``*`` in a completion word would meet the shell's file globbing)."""
    words = [k for k in echo_keys() if "*" not in k]
    for row in KEY_TABLE:
        suffix = row.key.removeprefix(f"{PREFIX}/<arm>/")
        if suffix.endswith("/<service>") and "/".join(suffix.split("/")[:-1]) + "/*" in echo_keys():
            words += [f"{suffix.rsplit('/', 1)[0]}/{s.value}" for s in Service]
    return tuple(dict.fromkeys(words))


def first_words() -> Mapping[str, tuple[str, ...]]:
    """The first positional argument's choices, per command."""
    return {"service": NAMES, "call": operation_names(), "echo": echo_words(),
            "wait": tuple(c.value for c in Condition), "completion": SHELLS}


def _options(parser: argparse.ArgumentParser) -> tuple[list[str], list[str]]:
    """(every option, the options that take a value) of ``parser``."""
    every: list[str] = []
    valued: list[str] = []
    for action in parser._actions:  # argparse has no public list of its options
        if action.help == argparse.SUPPRESS:
            continue
        every += action.option_strings
        if action.option_strings and action.nargs != 0:
            valued += action.option_strings
    return every, valued


def _actions(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    """The sub-commands of a command that has them (``certs init``, ...), by name; else none."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def bash_script(commands: Mapping[str, argparse.ArgumentParser]) -> str:
    """The completion function ``_jara_arm`` and its ``complete`` line."""
    words = first_words()
    cases, valued_all = [], set()
    for name, parser in commands.items():
        options, valued = _options(parser)
        valued_all.update(valued)
        lines = [f"        {name})", f"            opts={shlex.quote(' '.join(options))}"]
        actions = _actions(parser)
        if actions:  # the first positional word is the sub-command; the options are the sub-command's
            lines.append(f"            words={shlex.quote(' '.join(actions))}")
            lines.append('            case "${COMP_WORDS[2]}" in')
            for action, action_parser in actions.items():
                action_options, action_valued = _options(action_parser)
                valued_all.update(action_valued)
                lines.append(f"                {action}) opts={shlex.quote(' '.join(action_options))} ;;")
            lines.append("            esac")
        elif name in words:
            lines.append(f"            words={shlex.quote(' '.join(words[name]))}")
        if name == "call":  # the servo serves the Common operations only
            lines += ['            for w in "${COMP_WORDS[@]}"; do',
                      f"                [[ $w == --servo ]] && words={shlex.quote(' '.join(operation_names(True)))}",
                      "            done"]
        lines.append("            ;;")
        cases += lines
    valued_pattern = "|".join(sorted(valued_all)) or "--"
    return "\n".join([
        "# bash completion of jara-arm: source <(jara-arm completion bash)",
        "_jara_arm() {",
        '    local cur="${COMP_WORDS[COMP_CWORD]}" prev="${COMP_WORDS[COMP_CWORD-1]}"',
        '    local opts="" words="" i n=0',
        "    COMPREPLY=()",
        "    if (( COMP_CWORD == 1 )); then",
        f"        COMPREPLY=($(compgen -W {shlex.quote(' '.join(commands))} -- \"$cur\"))",
        "        return 0",
        "    fi",
        '    case "${COMP_WORDS[1]}" in',
        *cases,
        "    esac",
        '    if [[ $cur == -* ]]; then',
        '        COMPREPLY=($(compgen -W "$opts" -- "$cur"))',
        "        return 0",
        "    fi",
        '    case "$prev" in',
        f"        {valued_pattern}) return 0 ;;",  # an option's value: nothing to offer
        "    esac",
        "    for (( i = 2; i < COMP_CWORD; i++ )); do  # positional words before this one",
        '        [[ ${COMP_WORDS[i]} == -* ]] && continue',
        '        case "${COMP_WORDS[i-1]}" in',
        f"            {valued_pattern}) continue ;;",
        "        esac",
        "        n=$((n + 1))",
        "    done",
        '    (( n == 0 )) && COMPREPLY=($(compgen -W "$words" -- "$cur"))',
        "    return 0",
        "}",
        "complete -F _jara_arm jara-arm",
        "",
    ])

