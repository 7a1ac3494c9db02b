"""A ULog's data section read with numpy, for :func:`~mjxsysid.logs.ulog.read_ulog`.

pyulog reads a ULog one message at a time in Python (a few µs each: a 10-minute log of 2 million
messages takes seconds). Here the message boundaries are walked once (a size and a type per message),
every topic's data messages (``D``) are gathered at once into pyulog's subscription buffers, and the
rare other messages (subscriptions, parameters, info, logging, dropouts) go through pyulog's own
message classes, so the object is pyulog's ``ULog`` as its own loop would have built it. A file whose
messages do not walk cleanly (an unknown type, a data message of an unknown topic, a short payload:
corruption pyulog recovers from) and a file with appended data are left to pyulog's loop.
"""
from __future__ import annotations

import io

import numpy as np

from mjxsysid.logs.record import gather

KNOWN = frozenset(b"ADIMPQLCOS")
"""The data section's message types read here (pyulog's loop takes a file with any other)."""


def message_starts(data: bytes) -> np.ndarray | None:
    """Byte offsets (N,) of the messages in a ULog data section ``data`` (a uint16 size, a uint8 type, the
    body); a last message cut short is dropped. None when a size is 0 (corruption)."""
    out, i, n = [], 0, len(data) - 3
    add = out.append
    while i <= n:                                   # the one step per message: its size
        add(i)
        i += (data[i] | (data[i + 1] << 8)) + 3
    offs = np.asarray(out, np.int64)
    buf = np.frombuffer(data, np.uint8)
    if np.any((buf[offs] == 0) & (buf[offs + 1] == 0)):
        return None
    return offs if i == len(data) else offs[:-1]


def read_data_section(ULog, ulog, data: bytes) -> bool:
    """Fill ``ulog`` (an instance of pyulog's ``ULog`` class, its definitions read) from its data section
    ``data`` as pyulog's ``_read_file_data`` would, without a Python step per data message -> False (nothing changed) when
    the section does not walk cleanly."""
    offs = message_starts(data)
    if offs is None or not len(offs):
        return False
    buf = np.frombuffer(data, np.uint8)
    kind = buf[offs + 2]
    if not set(np.unique(kind).tolist()) <= KNOWN:
        return False
    size = buf[offs].astype(np.int64) | (buf[offs + 1].astype(np.int64) << 8)
    is_data = kind == ord("D")
    header = ULog._MessageHeader()
    subs = {}
    for o in offs[kind == ord("A")].tolist():
        header.initialize(data[o:o + 3])
        sub = ULog._MessageAddLogged(data[o + 3:o + 3 + header.msg_size], header, ulog._message_formats)
        subs[sub.msg_id] = sub
    d_offs, d_size = offs[is_data], size[is_data]
    msg_id = buf[d_offs + 3].astype(np.int64) | (buf[d_offs + 4].astype(np.int64) << 8)
    stamps = np.zeros(len(d_offs), np.uint64)
    for mid in np.unique(msg_id).tolist():
        if mid not in subs:
            return False
        sub, mine = subs[mid], msg_id == mid
        width = sub.dtype.itemsize
        if np.any(d_size[mine] - 2 < width) or np.any(d_size[mine] - 2 > sub.max_data_size):
            return False
        sub.buffer = bytearray(gather(buf, d_offs[mine] + 5, (np.uint8, (width,))).tobytes())
        at = d_offs[mine] + 5 + sub.timestamp_offset
        stamps[mine] = gather(buf, at, "<u8")
    # the latest data timestamp before each other message (pyulog stamps changed parameters and dropouts with it)
    latest = np.maximum.accumulate(np.concatenate([[ulog._last_timestamp], stamps]).astype(np.uint64))
    before = np.searchsorted(d_offs, offs[~is_data])
    for o, typ, k in zip(offs[~is_data].tolist(), kind[~is_data].tolist(), before.tolist()):
        if typ == ord("A"):
            continue
        ulog._last_timestamp = int(latest[k])
        header.initialize(data[o:o + 3])
        body = data[o + 3:o + 3 + header.msg_size]
        if typ == ord("I"):
            m = ULog._MessageInfo(body, header)
            ulog._msg_info_dict[m.key], ulog._msg_info_dict_types[m.key] = m.value, m.type
        elif typ == ord("M"):
            ulog._add_message_info_multiple(ULog._MessageInfo(body, header, is_info_multiple=True))
        elif typ == ord("P"):
            m = ULog._MessageInfo(body, header)
            ulog._changed_parameters.append((ulog._last_timestamp, m.key, m.value))
        elif typ == ord("Q"):
            ulog._add_parameter_default(ULog._MessageParameterDefault(body, header))
        elif typ == ord("L"):
            ulog._logged_messages.append(ULog.MessageLogging(body, header))
        elif typ == ord("C"):
            m = ULog.MessageLoggingTagged(body, header)
            ulog._logged_messages_tagged.setdefault(m.tag, []).append(m)
        elif typ == ord("O"):
            ulog._dropouts.append(ULog.MessageDropout(body, header, ulog._last_timestamp))
        elif typ == ord("S"):
            ulog._sync_seq_cnt += 1
    ulog._last_timestamp = int(latest[-1])
    ulog._subscriptions = {k: v for k, v in subs.items() if len(v.buffer)}
    return True


def load(ULog, path: str):
    """pyulog's ``ULog`` of the file at ``path``, its data section read by :func:`read_data_section`
    (pyulog's own loop where that declines)."""

    class FastULog(ULog):
        def _read_file_data(self, message_name_filter_list, read_until=None):
            if read_until is None and message_name_filter_list is None and not self.has_data_appended:
                start = self._file_handle.tell()
                if read_data_section(ULog, self, self._file_handle.read()):
                    self._file_handle = io.BytesIO(b"")        # the conversion below finds the buffers filled
                else:
                    self._file_handle.seek(start)
            super()._read_file_data(message_name_filter_list, read_until)

    return FastULog(path)

