"""What a posterior call found compiled ahead (mjxsysid/runtime/ahead.py)."""


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
