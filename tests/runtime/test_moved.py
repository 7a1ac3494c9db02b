"""Moved modules keep their old import path for one release, with a FutureWarning naming the new one."""
import importlib
import subprocess
import sys
import warnings

import pytest

from mjxsysid.runtime.moved import MOVED
from support.paths import ROOT


@pytest.mark.parametrize("old", ["mjxsysid.studies.decode", "mjxsysid.studies.noise", "mjxsysid.progress"])
def test_old_path_imports_the_new_module_with_a_warning(old):
    new = importlib.import_module(MOVED[old])
    parent = old.rpartition(".")[0]
    with warnings.catch_warnings():                 # the old parent package warns once on its own
        warnings.simplefilter("ignore", FutureWarning)
        importlib.import_module(parent)
    sys.modules.pop(old, None)
    with pytest.warns(FutureWarning, match=f"{old} moved to {MOVED[old]}"):
        mod = importlib.import_module(old)
    assert mod is new


def test_every_new_path_exists():
    """Each entry points at a module that imports (a typo would only surface in a user's import)."""
    for new in sorted(set(MOVED.values())):
        assert importlib.util.find_spec(new) is not None, new


def test_from_import_of_a_moved_top_level_module_warns():
    """`from mjxsysid import jsonout` (the old spelling) still works, and says where it went."""
    r = subprocess.run([sys.executable, "-W", "always::FutureWarning", "-c", "from mjxsysid import jsonout; print(jsonout.__name__)"],
                       capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "mjxsysid.runtime.jsonout"
    assert "mjxsysid.jsonout moved to mjxsysid.runtime.jsonout" in r.stderr
