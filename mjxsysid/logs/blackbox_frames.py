"""Betaflight blackbox frames decoded here, for :mod:`mjxsysid.logs.blackbox`: one pass over a log's bytes
with every field's decoding and predictor planned once from the header (orangebox, the reference it is
checked against, reads one byte per Python call: a 10-minute log at 500 Hz takes it seconds).

The format (Betaflight's blackbox documentation): header lines ``H name:value``, then frames, each a
marker byte and its fields. Main frames: intra (``I``, every field whole) and inter (``P``, fields
predicted from the frames before); slow (``S``), GPS (``G``), GPS home (``H``) and event (``E``)
frames are read past. A field is read with its encoding (variable-byte unsigned or zig-zag signed,
negative 14-bit, or a group: tag8_8svb, tag2_3s32, tag8_4s16), then its predictor adds what it
predicts (the previous value, a straight line or the average of the last two, the loop iteration's
increment, minthrottle, motor[0], 1500, vbatref, the minimum motor output). A main frame is kept when
the byte after it starts a frame, as the reference does; a frame cut short at the end is dropped.
"""
from __future__ import annotations

MARKERS = frozenset(b"IPSGHE")
END_OF_LOG = b"End of log\x00"


class Unsupported(ValueError):
    """A header this decoder does not plan (an encoding or predictor it does not know): the reference reads the log."""


def cast(text: str):
    """A header value as the reference reads it: hex ('0x…') and decimal integers, floats, else the text."""
    if text.startswith("0x"):
        return int(text, 16)
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def parse_headers(data: bytes, start: int) -> tuple[dict, int]:
    """The header lines from ``start`` -> ({name: value, or a list of values where it has commas}, where the
    frames start)."""
    headers, i = {}, start
    while data.startswith(b"H ", i):
        j = data.find(b"\n", i)
        if j < 0:
            break
        name, sep, value = data[i + 2:j].decode("ascii", "replace").partition(":")
        if sep:
            headers[name.strip()] = ([cast(v.strip()) for v in value.split(",")] if "," in value
                                     else cast(value.strip()))
        i = j + 1
    return headers, i


def _plan(headers: dict, kind: str, names=None):
    """The fields of frame ``kind`` as steps [(encoding, field indices, predictors)]: one step per field,
    or per group of fields that share a group encoding. -> (steps, field names)."""
    names = names or headers.get(f"Field {kind} name")
    if names is None:
        return None, None
    names = names if isinstance(names, list) else [names]
    n = len(names)

    def ints(key):
        v = headers.get(f"Field {kind} {key}", [0] * n)
        return (v if isinstance(v, list) else [v]) + [0] * (n - (len(v) if isinstance(v, list) else 1))
    enc, pred = ints("encoding"), ints("predictor")
    for e in enc:
        if e not in (0, 1, 3, 6, 7, 8, 9):
            raise Unsupported(f"field encoding {e} of {kind} frames")
    for p in pred:
        if p not in range(12):
            raise Unsupported(f"field predictor {p} of {kind} frames")
    steps, k = [], 0
    while k < n:
        e = enc[k]
        size = {6: 8, 7: 3, 8: 4}.get(e, 1)
        group = [k]
        while len(group) < size and k + len(group) < n and enc[k + len(group)] == e:
            group.append(k + len(group))
        if e in (7, 8) and len(group) != size:
            raise Unsupported(f"a group of {len(group)} fields of encoding {e}")
        steps.append((e if not (e == 6 and len(group) == 1) else 0, tuple(group)))
        k += len(group)
    return (steps, [pred[i] for i in range(n)]), list(map(str, names))


def _sx(v: int, bits: int) -> int:
    """``v``'s low ``bits`` bits as a two's-complement number."""
    v &= (1 << bits) - 1
    return v - (1 << bits) if v & (1 << (bits - 1)) else v


def _uvb_rest(data: bytes, i: int, b: int):
    """An unsigned variable-byte value whose first byte ``b`` (≥ 128) was read, ``i`` after it -> (value,
    next byte)."""
    v, shift = b & 0x7F, 7
    for _ in range(4):
        b = data[i]
        i += 1
        v |= (b & 0x7F) << shift
        if b < 128:
            return v, i
        shift += 7
    return 0, i                                                  # five bytes, none the last: read as 0


def _tag2_3s32(data: bytes, i: int):
    """Three values of one tag2_3s32 group from byte ``i`` -> (values, next byte)."""
    lead = data[i]
    i += 1
    sel = lead >> 6
    if sel == 0:
        return (_sx(lead >> 4, 2), _sx(lead >> 2, 2), _sx(lead, 2)), i
    if sel == 1:
        b = data[i]
        return (_sx(lead, 4), _sx(b >> 4, 4), _sx(b, 4)), i + 1
    if sel == 2:
        return (_sx(lead, 6), _sx(data[i], 6), _sx(data[i + 1], 6)), i + 2
    vals = []
    for _ in range(3):
        width = (lead & 3) + 1
        if len(data) < i + width:
            raise IndexError("frame cut short")
        v = int.from_bytes(data[i:i + width], "little")
        i += width
        vals.append(v if width == 4 else _sx(v, 8 * width))
        lead >>= 2
    return vals, i


def _tag8_4s16(data: bytes, i: int):
    """Four values of one tag8_4s16 group (data version 2) from byte ``i`` -> (values, next byte)."""
    sel = data[i]
    i += 1
    nibble, buf, vals = False, 0, []
    for _ in range(4):
        t = sel & 3
        if t == 0:
            v = 0
        elif t == 1:
            if not nibble:
                buf = data[i]
                i += 1
                v = _sx(buf >> 4, 4)
            else:
                v = _sx(buf, 4)
            nibble = not nibble
        elif t == 2:
            if not nibble:
                v = _sx(data[i], 8)
                i += 1
            else:
                c = data[i]
                i += 1
                v = _sx(((buf & 0x0F) << 4) | (c >> 4), 8)
                buf = c
        else:
            if not nibble:
                v = _sx((data[i] << 8) | data[i + 1], 16)
                i += 2
            else:
                c, d = data[i], data[i + 1]
                i += 2
                v = _sx(((buf & 0x0F) << 12) | (c << 4) | (d >> 4), 16)
                buf = d
        vals.append(v)
        sel >>= 2
    return vals, i


def _vb(var: str, signed: bool, pad: str) -> list[str]:
    """Source lines reading one variable-byte value into ``var`` (zig-zag decoded when ``signed``)."""
    out = [f"{pad}b = data[i]", f"{pad}i += 1", f"{pad}if b < 128:", f"{pad}    {var} = b",
           f"{pad}elif data[i] < 128:", f"{pad}    {var} = (b & 0x7F) | (data[i] << 7)", f"{pad}    i += 1",
           f"{pad}else:", f"{pad}    {var}, i = _uvb_rest(data, i, b)"]
    if signed:
        out.append(f"{pad}{var} = (({var} & 0xFFFFFFFF) >> 1) ^ -({var} & 1)")
    return out


PREDICT = {1: "r{k} += p1[{k}]", 2: "r{k} += 2 * p1[{k}] - p2[{k}]",
           3: "s = p1[{k}] + p2[{k}]\n    r{k} += s // 2 if s >= 0 else -(-s // 2)",
           4: "r{k} += {minthrottle}", 5: "r{k} += r{motor0}", 6: "r{k} = 1 + p1[{k}] + skipped", 8: "r{k} += 1500",
           9: "r{k} += {vbatref}", 10: "r{k} += p2[{k}]", 11: "r{k} += {minmotor}"}
"""Each predictor as the source line adding its prediction to the raw value ``r{k}`` of field k
(p1, p2: the last two main frames; skipped: the loop iterations not logged since the last)."""


def compile_frame(plan, consts: dict):
    """A function reading one frame of ``plan`` (:func:`_plan`): ``read(data, i, p1, p2, skipped) -> (next
    byte, values)``, written as straight-line Python (one block per field or group, then one line per
    predictor) so that a frame costs no loop over its fields. ``consts``: minthrottle, vbatref, minmotor
    (the headers' values) and motor0 (motor[0]'s field index, for predictor 5)."""
    steps, preds = plan
    src = ["def read(data, i, p1, p2, skipped):"]
    for enc, idx in steps:
        if enc in (0, 1, 3):
            src += _vb(f"r{idx[0]}", enc == 0, "    ")
            if enc == 3:
                r = f"r{idx[0]}"
                src.append(f"    {r} = -((({r} | 0xFFFFC000) - (1 << 32)) if {r} & 0x2000 else {r})")
        elif enc == 6:
            src += ["    h = data[i]", "    i += 1"]
            for bit, k in enumerate(idx):
                src += [f"    if h & {1 << bit}:"] + _vb(f"r{k}", True, "        ") + ["    else:", f"        r{k} = 0"]
        elif enc in (7, 8):
            group = "_tag2_3s32" if enc == 7 else "_tag8_4s16"
            src.append(f"    ({', '.join(f'r{k}' for k in idx)},), i = {group}(data, i)")
        else:
            src.append(f"    r{idx[0]} = 0")
    for k, pr in enumerate(preds):
        if pr == 5 and (consts["motor0"] is None or consts["motor0"] >= k):
            continue
        if pr in PREDICT:
            src.append("    " + PREDICT[pr].format(k=k, **consts))
    src.append(f"    return i, [{', '.join(f'r{k}' for k in range(len(preds)))}]")
    scope = {"_uvb_rest": _uvb_rest, "_tag2_3s32": _tag2_3s32, "_tag8_4s16": _tag8_4s16}
    exec("\n".join(src), scope)                                    # noqa: S102  (source built above, no input text)
    return scope["read"]


def _event(data: bytes, i: int) -> tuple[int, bool]:
    """Read past an event frame's body from ``i`` (its type byte) -> (the byte after it, log ended)."""
    def uvb(i):
        for _ in range(5):
            b = data[i]
            i += 1
            if b < 128:
                break
        return i
    kind = data[i]
    i += 1
    if kind == 255:
        return (i + len(END_OF_LOG), True) if data.startswith(END_OF_LOG, i) else (i, False)
    if kind in (0, 15):                                         # sync beep, disarm
        return uvb(i), False
    if kind in (14, 30):                                        # logging resume, flight mode
        return uvb(uvb(i)), False
    if kind == 13:                                              # in-flight adjustment
        return (i + 5 if data[i] & 0x80 else uvb(i + 1)), False
    return i, False


def decode_frames(data: bytes, start: int, end: int) -> tuple[dict, list[str], list[list[int]]]:
    """One blackbox log in ``data[start:end]`` -> (headers without the field definitions, the main
    fields' names, the main frames' values [[int] per frame] in file order). Unsupported: a header
    this decoder does not plan."""
    headers, i = parse_headers(data, start)
    plan_i, names = _plan(headers, "I")
    if plan_i is None:
        raise Unsupported("no 'Field I name' header")
    plan_p, _ = _plan(headers, "P", names) if "Field P encoding" in headers else (None, None)
    others = {m: _plan(headers, m)[0] for m in "SGH"}
    minthrottle = headers.get("minthrottle", 0)
    vbatref = headers.get("vbatref", 0)
    motor_out = headers.get("motorOutput", [0, 0])
    minmotor = motor_out[0] if isinstance(motor_out, list) else motor_out
    i_interval = max(int(headers.get("I interval", 1) or 1), 1)
    p = headers.get("P interval", 0)
    num, den = (1, int(p)) if isinstance(p, int) else (int(str(p).split("/")[0]), int(str(p).split("/")[1]))
    den = max(den, 1)
    n = len(names)
    i_iter = names.index("loopIteration") if "loopIteration" in names else None
    consts = {"minthrottle": int(minthrottle), "vbatref": int(vbatref), "minmotor": int(minmotor),
              "motor0": names.index("motor[0]") if "motor[0]" in names else None}
    version = headers.get("Data version", 1)
    plans = [plan for plan in (plan_i, plan_p, *others.values()) if plan is not None]
    if not (isinstance(version, int) and version >= 2) and any(e == 8 for plan in plans for e, _ in plan[0]):
        raise Unsupported("tag8_4s16 of data version 1")
    read = {0x49: compile_frame(plan_i, consts), 0x50: compile_frame(plan_p, consts) if plan_p else None}
    skip = {ord(m): compile_frame((plan[0], [0] * len(plan[1])), consts) for m, plan in others.items() if plan}
    data = data[:end]
    frames, prev1, prev2 = [], None, None
    zeros = [0] * n
    last_iter_seen, last_iter = -1, 0
    last_pos, corrupt = i, False
    while i < end:
        marker = data[i]
        if marker not in MARKERS:
            i = i + 1 if corrupt else last_pos + 1
            corrupt = True
            continue
        corrupt, last_pos = False, i
        try:
            if marker == 0x45:                                       # E
                i, ended = _event(data, i + 1)
                if ended:
                    break
                continue
            if marker not in read:                                   # S, G, H: read past
                i = skip[marker](data, i + 1, zeros, zeros, 0)[0] if marker in skip else i + 1
                continue
            if read[marker] is None:
                i += 1
                continue
            skipped = 0
            if last_iter_seen != -1:
                index = last_iter_seen + 1
                while not (index % i_interval + num - 1) % den < num:
                    index += 1
                skipped = index - last_iter_seen - 1
            p1 = prev1 if prev1 is not None else zeros
            i, vals = read[marker](data, i + 1, p1, prev2 if prev2 is not None else p1, skipped)
        except IndexError:                                          # a frame cut short at the end
            break
        cur_iter = vals[i_iter] if i_iter is not None else 0
        last_iter_seen = cur_iter
        if last_iter >= cur_iter and 5000 < cur_iter + last_iter:   # the loop iteration ran backwards: dropped
            last_iter = cur_iter
            continue
        last_iter = cur_iter
        if i < end and data[i] not in MARKERS:                      # the next byte starts no frame: corrupt
            continue
        frames.append(vals)
        if marker == 0x49:
            prev1 = prev2 = vals
        else:
            prev2, prev1 = prev1, vals
    return {k: v for k, v in headers.items() if "Field" not in k}, names, frames
