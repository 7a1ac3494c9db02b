"""ROS bag messages read with numpy, for :mod:`mjxsysid.logs.rosbag`.

rosbags deserialises one message at a time into Python objects (about 20 µs each), and its ROS 1
reader builds a Python object per message of the bag's index when it opens it: a 10-minute bag of a
million messages takes half a minute. Here:

- :func:`fields` reads the fields a reader uses from a topic's raw messages at once, when they all
  have one length and one layout (the usual case: a topic's frame id and array lengths do not change):
  the offsets are walked once on the first message from the type's definition (ROS 1 packed, or CDR
  aligned), and every message is a row of one matrix;
- :func:`read_ros1` reads a ROS 1 bag's chunks (uncompressed, bz2 or lz4), its connections and its
  per-chunk index with numpy, no Python step per message; it checks the MD5 of each type read against
  the typestore the offsets are walked from before it gathers any message;
- :func:`read_mcap` reads an MCAP file (a ROS 2 bag's storage) the same way, from its chunks
  (uncompressed, zstd or lz4) and their message indexes, its types registered from its own schemas.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mjxsysid.logs.record import gather

DTYPES = {"bool": "u1", "int8": "i1", "uint8": "u1", "byte": "u1", "char": "u1", "int16": "<i2", "uint16": "<u2",
          "int32": "<i4", "uint32": "<u4", "float32": "<f4", "int64": "<i8", "uint64": "<u8", "float64": "<f8"}
SIZES = {t: np.dtype(d).itemsize for t, d in DTYPES.items()}
"""Bytes of each fixed-size ROS field type."""
ROS1_MAGIC = b"#ROSBAG V2.0"
MCAP_MAGIC = b"\x89MCAP0\r\n"
BASE, NAME, ARRAY, SEQUENCE = 1, 2, 3, 4
"""rosbags' Nodetype values."""


class Unsupported(Exception):
    """A definition the offsets are not walked for (the reader deserialises such a topic message by message)."""


def layout(typestore, msgtype: str, raw: bytes, cdr: bool) -> tuple[dict, list, int]:
    """The offsets of one serialised message ``raw`` of ``msgtype``: ({path: (offset, dtype, count)} of
    its numbers, [offsets of its length prefixes (strings, sequences)], its end). ``cdr``: ROS 2's CDR
    (a 4-byte encapsulation header, little-endian, fields aligned to their size), else ROS 1 (packed)."""
    if cdr and raw[1] != 1:
        raise Unsupported("big-endian CDR")
    out, prefixes = {}, []
    pos = 4 if cdr else 0

    def align(n):
        nonlocal pos
        if cdr:
            pos = 4 + -(-(pos - 4) // n) * n

    def length():
        nonlocal pos
        align(4)
        prefixes.append(pos)
        n = int.from_bytes(raw[pos:pos + 4], "little")
        pos += 4
        return n

    def base(path, typ, count):
        nonlocal pos
        if typ == "string":
            for _ in range(count):
                n = length()
                out.setdefault(path, (pos, "S", n))
                pos += n
            return
        if typ not in SIZES:
            raise Unsupported(typ)
        align(SIZES[typ])
        out[path] = (pos, DTYPES[typ], count)
        pos += SIZES[typ] * count

    def walk(typ, prefix):
        for name, (node, detail) in typestore.fielddefs[typ][1]:
            path = prefix + name
            if node == NAME:
                walk(detail, path + ".")
            elif node == BASE:
                base(path, detail[0], 1)
            elif node in (ARRAY, SEQUENCE):
                (sub, subdetail), count = detail
                if node == SEQUENCE:
                    count = length()
                if sub == BASE:
                    base(path, subdetail[0], count)
                else:
                    for i in range(count):
                        walk(subdetail, f"{path}[{i}].")
            else:
                raise Unsupported(str(node))

    walk(msgtype, "")
    return out, prefixes, pos


def fields(typestore, msgtype: str, raws, cdr: bool, paths) -> dict | None:
    """The numeric fields ``paths`` (and ``header.frame_id`` of the first message, a str) of the messages
    ``raws`` of ``msgtype`` ([bytes], or (N, length) uint8 of messages of one length) -> {path: (N,) or
    (N, count) array}, or None when they differ in length or layout (or a definition is not walked)."""
    if isinstance(raws, np.ndarray):
        mat = raws
    else:
        if not raws or len({len(r) for r in raws}) != 1:
            return None
        mat = np.frombuffer(b"".join(raws), np.uint8).reshape(len(raws), len(raws[0]))
    if not len(mat):
        return None
    first = mat[0].tobytes()
    try:
        offsets, prefixes, end = layout(typestore, msgtype, first, cdr)
    except (Unsupported, KeyError, IndexError):
        return None
    if end > len(first) or any(p not in offsets for p in paths):
        return None
    for p in prefixes:                                   # every length prefix the same: one layout
        col = mat[:, p:p + 4]
        if np.any(col != col[0]):
            return None
    out = {}
    for p in paths:
        off, dt, count = offsets[p]
        size = np.dtype(dt).itemsize
        v = np.ascontiguousarray(mat[:, off:off + size * count]).view(dt)
        out[p] = v[:, 0] if count == 1 else v
    if "header.frame_id" in offsets:
        off, _, count = offsets["header.frame_id"]
        out["header.frame_id"] = first[off:off + count].split(b"\0")[0].decode("utf-8", "replace")
    return out


def time_order(t):
    """The stable order sorting times ``t`` (N,), or None when they are sorted already."""
    return None if np.all(t[1:] >= t[:-1]) else np.argsort(t, kind="stable")


# ---- ROS 1 bags

@dataclass
class Connection:
    """A connection of a bag: its topic, type (rosbags' normalised name), number of messages and id."""
    topic: str
    msgtype: str
    msgcount: int
    id: int = 0
    md5sum: str = ""


@dataclass
class Bag:
    """A bag read with numpy: ``connections``, ``start_time`` (ns, the earliest receive time) and
    per connection id its receive times (N,) ns and raw messages [bytes] in receive-time order."""
    connections: list
    start_time: int
    messages: dict = field(default_factory=dict)


def _header(data: bytes, pos: int, end: int) -> dict:
    """A ROS 1 bag record header's fields {name: bytes value}."""
    out = {}
    while pos < end:
        n = int.from_bytes(data[pos:pos + 4], "little")
        name, _, value = data[pos + 4:pos + 4 + n].partition(b"=")
        out[name.decode()] = value
        pos += 4 + n
    return out


def _chunk_bytes(head: dict, body: bytes) -> bytes:
    kind = head.get("compression", b"none")
    if kind == b"none":
        return body
    if kind == b"bz2":
        import bz2
        return bz2.decompress(body)
    if kind == b"lz4":
        from lz4.frame import decompress
        return decompress(body)
    raise Unsupported(f"chunk compression {kind!r}")


def read_ros1(data: bytes, typestore, types) -> Bag | None:
    """A ROS 1 bag's bytes ``data`` -> its connections and messages (:class:`Bag`), or None when it
    is not read here (an unindexed or unknown record, a compression other than bz2 and lz4, a connection
    of one of ``types`` whose definition's MD5 is not the typestore's: rosbags reads it)."""
    from rosbags.typesys.msg import normalize_msgtype
    if not data.startswith(ROS1_MAGIC + b"\n"):
        return None
    pos, n = 13, len(data)
    conns, chunk, per_conn = {}, None, {}
    try:
        while pos + 4 <= n:
            hl = int.from_bytes(data[pos:pos + 4], "little")
            head = _header(data, pos + 4, pos + 4 + hl)
            dl = int.from_bytes(data[pos + 4 + hl:pos + 8 + hl], "little")
            body = data[pos + 8 + hl:pos + 8 + hl + dl]
            op = head.get("op", b"\0")[0]
            if op == 0x05:                                             # chunk
                chunk = np.frombuffer(_chunk_bytes(head, body), np.uint8)
            elif op == 0x04 and chunk is not None:                     # the chunk's index, one connection
                cid = int.from_bytes(head["conn"], "little")
                idx = np.frombuffer(body, [("sec", "<u4"), ("nsec", "<u4"), ("off", "<u4")])
                off = idx["off"].astype(np.int64)
                hlen = gather(chunk, off, "<u4").astype(np.int64)
                dlen = gather(chunk, off + 4 + hlen, "<u4").astype(np.int64)
                t = idx["sec"].astype(np.int64) * 1_000_000_000 + idx["nsec"]
                per_conn.setdefault(cid, []).append((t, chunk, off + 8 + hlen, dlen))
            elif op == 0x07:                                           # connection
                cid = int.from_bytes(head["conn"], "little")
                info = _header(body, 0, len(body))
                conns[cid] = (head["topic"].decode(), normalize_msgtype(info["type"].decode()), info["md5sum"].decode())
            elif op not in (0x03, 0x06):
                return None
            pos += 8 + hl + dl
    except (KeyError, IndexError, ValueError, Unsupported):
        return None
    if not per_conn or set(per_conn) - set(conns):
        return None
    read = [conns[cid][1:] for cid in per_conn if conns[cid][1] in types]          # (msgtype, md5) of each
    if not all(md5_matches(typestore, msgtype, md5) for msgtype, md5 in read):
        return None
    return _bag(conns, per_conn)


def _bag(conns: dict, per_conn: dict) -> Bag:
    """A :class:`Bag` of ``conns`` {id: (topic, msgtype, md5 or "")} and ``per_conn`` {id: [(receive times
    (n,) ns, chunk (B,) uint8, data starts (n,), data lengths (n,))]}: each connection's messages in
    time order, one matrix where they share a length."""
    bag = Bag([], 0)
    for cid, parts in per_conn.items():
        topic, msgtype, md5 = conns[cid]
        t = np.concatenate([p[0] for p in parts])
        order = time_order(t)
        lengths = np.concatenate([p[3] for p in parts])
        if np.all(lengths == lengths[0]):                         # one length: a matrix, no step per message
            raw = np.concatenate([gather(c, start, (np.uint8, (int(lengths[0]),))) for _, c, start, _ in parts])
        else:
            raw = [bytes(c[a:a + d]) for _, c, start, ln in parts for a, d in zip(start.tolist(), ln.tolist())]
        if order is not None:
            t, raw = t[order], (raw[order] if isinstance(raw, np.ndarray) else [raw[i] for i in order.tolist()])
        bag.messages[cid] = (t, raw)
        bag.connections.append(Connection(topic, msgtype, len(t), cid, md5))
    bag.start_time = min(int(t[0]) for t, _ in bag.messages.values())
    return bag


# ---- MCAP (ROS 2)



def _u(data, i: int, n: int) -> int:
    return int.from_bytes(data[i:i + n], "little")


def _text(data, i: int) -> tuple[str, int]:
    n = _u(data, i, 4)
    return bytes(data[i + 4:i + 4 + n]).decode("utf-8", "replace"), i + 4 + n


def _decompress(kind: str, body, size: int) -> bytes:
    if kind == "":
        return bytes(body)
    if kind == "zstd":
        import zstandard
        return zstandard.ZstdDecompressor().decompress(bytes(body), max_output_size=size)
    if kind == "lz4":
        from lz4.frame import decompress
        return decompress(bytes(body))
    raise Unsupported(f"MCAP chunk compression {kind!r}")


def _schema_records(chunk: bytes, schemas: dict, channels: dict) -> None:
    """The schema and channel records inside a chunk's records (they precede the messages using them)."""
    i, n = 0, len(chunk)
    while i + 9 <= n:
        op, size = chunk[i], _u(chunk, i + 1, 8)
        if op in (0x03, 0x04):
            _definition(op, memoryview(chunk)[i + 9:i + 9 + size], schemas, channels)
        elif op == 0x05 and channels:
            return
        i += 9 + size


def _definition(op: int, body, schemas: dict, channels: dict) -> None:
    if op == 0x03:                                                # schema: id, name, encoding, data
        sid = _u(body, 0, 2)
        name, j = _text(body, 2)
        enc, j = _text(body, j)
        schemas[sid] = (name, enc, bytes(body[j + 4:j + 4 + _u(body, j, 4)]).decode("utf-8", "replace"))
    else:                                                         # channel: id, schema id, topic, encoding
        cid, sid = _u(body, 0, 2), _u(body, 2, 2)
        topic, j = _text(body, 4)
        enc, _ = _text(body, j)
        channels[cid] = (topic, sid, enc)


def read_mcap(data: bytes, typestore):
    """An MCAP file's bytes ``data`` -> (its connections and messages (:class:`Bag`, times in ns), the
    typestore with its schemas registered), or None when it is not read here (no message index, a
    compression other than zstd and lz4, a schema not in ros2msg, a message encoding not CDR)."""
    from rosbags.typesys import get_types_from_msg
    if not data.startswith(MCAP_MAGIC):
        return None
    view = memoryview(data)
    i, n = len(MCAP_MAGIC), len(data)
    schemas, channels, chunks, per_conn = {}, {}, [], {}
    try:
        while i + 9 <= n:
            op, size = data[i], _u(data, i + 1, 8)
            body = view[i + 9:i + 9 + size]
            if op == 0x06:                                        # chunk
                usize = _u(body, 16, 8)
                kind, j = _text(body, 28)
                chunk = _decompress(kind, body[j + 8:j + 8 + _u(body, j, 8)], usize)
                if not chunks:
                    _schema_records(chunk, schemas, channels)
                chunks.append(np.frombuffer(chunk, np.uint8))
            elif op == 0x07 and chunks:                           # the last chunk's message index, one channel
                cid = _u(body, 0, 2)
                idx = np.frombuffer(body[6:6 + _u(body, 2, 4)], [("t", "<u8"), ("off", "<u8")])
                c = chunks[-1]
                off = idx["off"].astype(np.int64)
                if len(off) and np.any(c[off] != 0x05):
                    return None
                length = gather(c, off + 1, "<u8").astype(np.int64) - 22
                per_conn.setdefault(cid, []).append((idx["t"].astype(np.int64), c, off + 31, length))
            elif op in (0x03, 0x04):
                _definition(op, body, schemas, channels)
            elif op == 0x02:                                      # footer
                break
            i += 9 + size
    except (IndexError, ValueError, Unsupported, ImportError):
        return None
    if not per_conn or any(cid not in channels or channels[cid][1] not in schemas for cid in per_conn):
        return None
    types = {}
    for cid in per_conn:
        topic, sid, enc = channels[cid]
        name, senc, text = schemas[sid]
        if enc != "cdr" or senc != "ros2msg":
            return None
        types.update(get_types_from_msg(text, name))
    try:
        typestore.register(types)
    except Exception:  # a schema that clashes with the typestore's definition
        return None
    conns = {cid: (channels[cid][0], schemas[channels[cid][1]][0], "") for cid in per_conn}
    return _bag(conns, per_conn), typestore


def md5_matches(typestore, msgtype: str, md5sum: str) -> bool:
    """Is a bag's MD5 ``md5sum`` of ``msgtype`` the typestore's (the same definition)?"""
    try:
        return typestore.generate_msgdef(msgtype, ros_version=1)[1] == md5sum
    except Exception:  # a type the typestore lacks
        return False
