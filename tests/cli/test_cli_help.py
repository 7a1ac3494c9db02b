"""`mjxsysid --help` and every command's flags, as they stood before the CLI was split into one
module per command group (tests/data/cli_help.json): a changed flag, default or help text fails
here, so it is changed on purpose (regenerate the file) or not at all."""
import json

from mjxsysid.cli import build_parser
from support.paths import DATA

GOLDEN = DATA / "cli_help.json"


def _helps() -> dict:
    p = build_parser()
    sub = next(a for a in p._actions if a.__class__.__name__ == "_SubParsersAction")
    return {"mjxsysid": p.format_help(), **{n: sp.format_help() for n, sp in sub.choices.items()}}


def test_every_command_and_flag_unchanged(monkeypatch):
    monkeypatch.setenv("COLUMNS", "100")  # argparse wraps help text to the terminal width
    want = json.loads(GOLDEN.read_text())
    got = _helps()
    assert sorted(got) == sorted(want)
    for name in want:
        assert got[name] == want[name], f"`mjxsysid {name} --help` changed"
