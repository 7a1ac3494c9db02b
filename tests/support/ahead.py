"""What a posterior call found compiled ahead (mjxsysid/runtime/ahead.py), and which programs it ran from files
(mjxsysid/runtime/exported.py)."""


def record_waits(monkeypatch) -> list:
    """Spy on :meth:`Ahead.wait` while ``monkeypatch`` holds: -> a list that fills with (kind, found) per wait, kind
    the name's first part ("smc", "nuts") and found whether the thread had compiled that program."""
    from mjxsysid.runtime.ahead import Ahead
    waits, wait = [], Ahead.wait

    def spy(self, name):
        waits.append((name[0], wait(self, name)))
        return waits[-1][1]
    monkeypatch.setattr(Ahead, "wait", spy)
    return waits


def record_exported(monkeypatch) -> set:
    """Spy on the programs run from their exported files while ``monkeypatch`` holds: -> a set that fills with
    each one's name ("nuts", "smc", "fit_ls", …; a program JAX refused to serialize runs jitted, and is not in it)."""
    from mjxsysid.runtime import exported
    names, runner = set(), exported._runner

    def spy(path):
        names.add(path.rsplit("/", 1)[-1].rsplit("-", 1)[0])
        return runner(path)
    monkeypatch.setattr(exported, "_runner", spy)
    return names
