"""Every option a command's help names exists (issue 42: help that no longer told the truth named options that
were gone or belonged elsewhere): in the command itself, or in the command the sentence names."""

from __future__ import annotations

import re
from typing import Any

import typer

from trafficgeo.cli import app

FLAG = re.compile(r"(?<![\w-])--[a-z][a-z0-9-]*")
SUMO_OPTIONS = {"--fcd-output"}  # SUMO's own options, named where its files are meant


def _commands() -> dict[str, Any]:
    root = typer.main.get_command(app)
    out: dict[str, Any] = {}

    def walk(cmd: Any, prefix: str) -> None:
        if hasattr(cmd, "list_commands"):  # a group (typer's own click)
            ctx = type(root).context_class(cmd)
            for name in cmd.list_commands(ctx):
                walk(cmd.get_command(ctx, name), f"{prefix} {name}".strip())
        else:
            out[prefix] = cmd

    walk(root, "")
    return out


def _options(cmd: Any) -> set[str]:
    return {o for p in cmd.params for o in (*p.opts, *p.secondary_opts) if o.startswith("--")} | {"--help"}


def test_every_option_named_in_help_exists() -> None:
    commands = _commands()
    assert "calibrate" in commands and "calibrate-ortho" in commands and "batch run" in commands
    wrong = []
    for name, cmd in commands.items():
        texts = [cmd.help or ""] + [getattr(p, "help", None) or "" for p in cmd.params]
        for text in texts:
            text = " ".join(text.split())
            for flag in set(FLAG.findall(text)):
                if flag in _options(cmd) or (flag in SUMO_OPTIONS and "sumo" in text.lower()):
                    continue
                # a sentence about another command may name that command's options
                others = [n for n in commands if n != name and re.search(rf"(?<![\w-]){re.escape(n)}(?![\w-])", text)]
                if any(flag in _options(commands[n]) for n in others):
                    continue
                wrong.append(f"{name}: {flag} in {text[:90]!r}")
    assert not wrong, "\n".join(wrong)
