"""`python -m mjxsysid.cli ...`, as the `mjxsysid` command."""
import sys

from mjxsysid.cli import entry

sys.exit(entry())
