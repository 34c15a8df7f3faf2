"""``jara-arm completion bash``: a bash completion script for the commands, their options, operation
names (``call``), keys (``echo``) and conditions (``wait``).

Generated from the commands (``cli.COMMANDS``): their parsers give the options,
the actions (``certs init``...) and the choices of the first positional argument;
a command whose first argument takes free text says what to offer (``Command.words``).
So it never lags behind them: ``source <(jara-arm completion bash)``, or save it under
``/etc/bash_completion.d/``.
"""

from __future__ import annotations

import argparse
import shlex
from collections.abc import Mapping

from .command import Command

SHELLS = ("bash",)


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


def _first_words(command: Command, parser: argparse.ArgumentParser) -> tuple[str, ...]:
    """What bash offers for the first positional argument: the command's words, else the argument's choices."""
    if command.words:
        return command.words
    first = next((a for a in parser._actions if not a.option_strings), None)
    return tuple(first.choices or ()) if first is not None else ()


def bash_script(commands: Mapping[str, tuple[Command, argparse.ArgumentParser]]) -> str:
    """The completion function ``_jara_arm`` and its ``complete`` line."""
    cases, valued_all = [], set()
    for name, (command, parser) in commands.items():
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
        elif words := _first_words(command, parser):
            lines.append(f"            words={shlex.quote(' '.join(words))}")
        for option, option_words in command.option_words.items():
            lines += ['            for w in "${COMP_WORDS[@]}"; do',
                      f"                [[ $w == {option} ]] && words={shlex.quote(' '.join(option_words))}",
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


def _arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("shell", choices=SHELLS)


def _run(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    # Imported here: the table of the commands holds this one.
    from .cli import command_parsers

    print(bash_script(command_parsers()), end="")
    return 0


COMMAND = Command(
    "completion", arguments=_arguments, run=_run,
    help="print a shell completion script",
    description="Print the completion script of jara-arm (commands, options, operation names, "
    "keys): source <(jara-arm completion bash)")
