"""mjxsysid: decode the latent of a frozen adaptive quadrotor policy into distributions of
physical models (MuJoCo/MJX, JAX).

The common path, as functions (imported lazily: ``import mjxsysid`` loads neither JAX nor
MuJoCo and prints nothing)::

    import mjxsysid
    res = mjxsysid.fly(mjxsysid.paper_vehicle(), controller="policy")   # FlightResult
    post = mjxsysid.decode(res)                     # or mjxsysid.decode("flight.csv")
    post = mjxsysid.identify("flight.ulg")          # the log alone: a LogPosterior

See :mod:`mjxsysid.api` and the README's "Python API" section.
"""
__version__ = "0.1.0"

_API = ("Finding", "FlightResult", "LogError", "check_log", "decode", "fly", "load_vehicle", "paper_vehicle", "prior_vehicles",
        "read_ulog", "save_vehicle", "to_theta")
__all__ = list(_API) + ["identify", "__version__"]


from mjxsysid.runtime.moved import install as _install_moved, moved_attribute as _moved_attribute

_install_moved()   # old import paths of moved modules still import, with a FutureWarning


def __getattr__(name):
    if name == "identify":                 # the room, callable: mjxsysid.identify(log) -> LogPosterior
        import importlib
        return importlib.import_module("mjxsysid.identify")
    if name in _API:
        from mjxsysid import api
        return getattr(api, name)
    old = _moved_attribute(name)
    if old is not None:
        return old
    raise AttributeError(f"module 'mjxsysid' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_API))
