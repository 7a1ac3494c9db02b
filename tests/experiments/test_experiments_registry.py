"""Every registered experiment has the common signature, and its results.json records the seed and
the exact call (every argument, defaults included) when it runs through the registry."""
import inspect
import json

import pytest

from mjxsysid.experiments import EXPERIMENTS, get_experiment
from mjxsysid.experiments.common import write_results


@pytest.mark.parametrize("name", list(EXPERIMENTS))
def test_common_signature(name):
    params = inspect.signature(get_experiment(name)).parameters
    assert list(params)[0] == "out"
    for p in ("quick", "policy", "seed", "progress"):
        assert p in params and params[p].kind is inspect.Parameter.KEYWORD_ONLY, (name, p)


def test_results_record_the_seed_and_call(tmp_path, monkeypatch):
    import mjxsysid.experiments.lag_oracle as mod

    def fake(out, *, quick=False, policy=None, seed=5, progress=True):
        return write_results(out, "lag-oracle", config={"quick": quick}, seeds={"seed": seed},
                             numbers={"headline": {}}, table_md="", t0=0.0)

    monkeypatch.setattr(mod, "run", fake)
    get_experiment("lag-oracle")(tmp_path, quick=True, progress=False)
    res = json.loads((tmp_path / "results.json").read_text())
    assert res["seed"] == 5
    assert res["call"] == {"experiment": "lag-oracle", "function": "mjxsysid.experiments.lag_oracle:run",
                           "arguments": {"out": str(tmp_path), "quick": True, "policy": None, "seed": 5}}


def test_unknown_experiment_names_the_known_ones():
    with pytest.raises(ValueError, match="lag-oracle"):
        get_experiment("nope")
