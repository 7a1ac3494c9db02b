"""Loading decoders for a policy: the shipped ones or a folder, checked against the policy whose
latents they were trained on (a decoder of another policy's latent would decode nonsense)."""
from __future__ import annotations

from pathlib import Path

from mjxsysid.cfm.sample import Decoder
from mjxsysid.cfm.sequence import SequenceDecoder
from mjxsysid.policy.interface import PRETRAINED_DIR, resolve_policy


def load_decoders(decoders=None, policy=None, *, warn=None,
                  allow_mismatch: bool = False) -> tuple[Decoder, Decoder]:
    """(CFM, Regression) decoders from the folder ``decoders`` (default: the folder where the
    policy's decoders ship; see :class:`~mjxsysid.policy.interface.PolicyRef`).

    Decoders trained on another policy's latents than ``policy``'s (their provenance records
    the weights' sha256) are an error: another policy's latent means something else, so the
    decoded models would be meaningless. ``allow_mismatch=True`` turns the error into a
    warning (told to ``warn(msg)``). A file of the wrong kind (``cfm.npz`` holding a
    regression decoder, …) is an error too."""
    ref = resolve_policy(policy) if policy is not None else None
    d = Path(decoders) if decoders is not None else (ref.decoders_dir if ref else PRETRAINED_DIR)
    for f in ("cfm.npz", "regression.npz"):
        if not (d / f).is_file():
            hint = "" if decoders is not None else (
                f" (no shipped decoders for {ref.label}: train them with `mjxsysid collect "
                f"--policy ...` and `mjxsysid train-cfm`, then pass --decoders DIR)" if ref else "")
            raise FileNotFoundError(f"decoder not found: {d / f}{hint}")
    cfm, reg = Decoder.load(d / "cfm.npz"), Decoder.load(d / "regression.npz")
    for dec, f, kind in ((cfm, "cfm.npz", "cfm"), (reg, "regression.npz", "regression")):
        if dec.kind != kind:
            raise ValueError(f"{d / f}: holds a {dec.kind} decoder, expected {kind}")
    if ref is not None:
        for dec, f in ((cfm, "cfm.npz"), (reg, "regression.npz")):
            if not _trained_for(dec, d / f, ref, allow_mismatch, warn, "mjxsysid collect + train-cfm"):
                break
    return cfm, reg


def _trained_for(dec, path, ref, allow_mismatch: bool, warn, how: str) -> bool:
    """Was ``dec`` (loaded from ``path``) trained on the latents of policy ``ref``? A mismatch is
    a ValueError, or with ``allow_mismatch`` a warning told to ``warn`` (then False)."""
    trained_on = dec.meta.get("data", {}).get("pairs_meta", {}).get("weights_sha256")
    if not trained_on or trained_on == ref.sha256():
        return True
    msg = (f"{path}: trained on the latents of another policy (weights sha256 {trained_on[:12]}…), "
           f"not {ref.label} ({ref.sha256()[:12]}…)")
    if not allow_mismatch:
        raise ValueError(msg + f"; pass the decoders trained for this policy ({how})")
    if warn is not None:
        warn("warning: " + msg)
    return False


def load_sequence_decoder(decoders=None, policy=None, *, echo=None, allow_mismatch: bool = False):
    """The sequence decoder ``cfm_seq.npz`` beside the policy's decoders (or in ``decoders``),
    or None (``echo`` is told, so callers can fall back to single-latent decoding). As for
    :func:`load_decoders`, one trained on another policy's latents is an error unless
    ``allow_mismatch`` (then a warning told to ``echo``)."""
    ref = resolve_policy(policy) if policy is not None else None
    d = Path(decoders) if decoders is not None else (ref.decoders_dir if ref else PRETRAINED_DIR)
    path = d / "cfm_seq.npz"
    if not path.is_file():
        if echo is not None:
            echo(f"no sequence decoder {path}: falling back to --window instant (single-latent decoding); "
                 "train one with `mjxsysid collect` and `mjxsysid train-cfm`")
        return None
    seq = SequenceDecoder.load(path)
    if ref is not None:
        _trained_for(seq, path, ref, allow_mismatch, echo, "mjxsysid collect --seconds + train-cfm")
    return seq
