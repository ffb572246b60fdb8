"""A run's data in files people take elsewhere: metrics as CSV or TensorBoard event files, queries with their
answers and images as a zip. No torch, no FastAPI: the routes stream what these return."""

import csv
import io
import struct
import time
import zipfile
from collections.abc import Iterable, Iterator

from contract.store import Store


def metrics_csv(store: Store, *, run_id: int) -> Iterator[str]:
    """One row per step, one column per metric name (empty where the metric was not recorded at that step)."""
    rows: dict[int, dict[str, float]] = {}
    for metric in store.metrics(run_id=run_id):
        rows.setdefault(metric.step, {})[metric.name] = metric.value
    names = sorted({name for values in rows.values() for name in values})
    buffer = io.StringIO()
    writer = csv.writer(buffer)
    writer.writerow(["step", *names])
    for step in sorted(rows):
        writer.writerow([step, *(repr(rows[step][name]) if name in rows[step] else "" for name in names)])
        if buffer.tell() > 65536:
            yield buffer.getvalue()
            buffer.seek(0)
            buffer.truncate()
    yield buffer.getvalue()


QUERY_COLUMNS = (
    "id", "env_step", "score", "strategy", "status", "answer", "labeler", "answered_at", "ground_truth_success",
    "created_at", "model_image", "display_image",
)  # fmt: skip


def queries_zip(store: Store, *, run_id: int) -> bytes:
    """queries.csv (one row per query, its answer and who gave it) and each query's two images under images/."""
    buffer = io.BytesIO()
    table = io.StringIO()
    writer = csv.writer(table)
    writer.writerow(QUERY_COLUMNS)
    with zipfile.ZipFile(buffer, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        for query in store.list_queries(run_id=run_id, limit=1_000_000, oldest_first=True):
            model_name, display_name = f"images/query-{query.id}-model.png", f"images/query-{query.id}-display.png"
            archive.writestr(model_name, store.query_image(query_id=query.id, resolution="model"))
            archive.writestr(display_name, store.query_image(query_id=query.id, resolution="display"))
            answer = "" if query.answer is None else ("yes" if query.answer else "no")
            writer.writerow([
                query.id, query.env_step, repr(query.score), query.strategy, query.status, answer, query.labeler or "",
                query.answered_at.isoformat() if query.answered_at else "",
                "" if query.ground_truth_success is None else repr(query.ground_truth_success),
                query.created_at.isoformat(), model_name, display_name,
            ])  # fmt: skip
        archive.writestr("queries.csv", table.getvalue())
    return buffer.getvalue()


# ---------------------------------------------------------------- TensorBoard event files, without TensorFlow
def _crc32c_table() -> list[int]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0x82F63B78 if crc & 1 else crc >> 1
        table.append(crc)
    return table


_CRC_TABLE = _crc32c_table()


def crc32c(data: bytes) -> int:
    crc = 0xFFFFFFFF
    for byte in data:
        crc = _CRC_TABLE[(crc ^ byte) & 0xFF] ^ (crc >> 8)
    return crc ^ 0xFFFFFFFF


def masked_crc(data: bytes) -> int:
    crc = crc32c(data)
    return (((crc >> 15) | (crc << 17)) + 0xA282EAD8) & 0xFFFFFFFF


def _varint(value: int) -> bytes:
    out = bytearray()
    while True:
        byte = value & 0x7F
        value >>= 7
        if value:
            out.append(byte | 0x80)
        else:
            out.append(byte)
            return bytes(out)


def _field(number: int, wire: int) -> bytes:
    return _varint((number << 3) | wire)


def _length_delimited(number: int, payload: bytes) -> bytes:
    return _field(number, 2) + _varint(len(payload)) + payload


def _event(wall_time: float, step: int, *, file_version: str | None = None, scalars: dict[str, float] | None = None):
    """tensorflow.Event: wall_time (1, double), step (2, int64), file_version (3) or summary (5) of
    Summary.Value{tag (1), simple_value (2, float)}."""
    message = _field(1, 1) + struct.pack("<d", wall_time) + _field(2, 0) + _varint(step)
    if file_version is not None:
        message += _length_delimited(3, file_version.encode())
    if scalars:
        values = b"".join(
            _length_delimited(1, _length_delimited(1, tag.encode()) + _field(2, 5) + struct.pack("<f", value))
            for tag, value in scalars.items()
        )
        message += _length_delimited(5, values)
    return message


def _record(data: bytes) -> bytes:
    """TFRecord framing: length, masked CRC32C of the length, data, masked CRC32C of the data."""
    length = struct.pack("<Q", len(data))
    return length + struct.pack("<I", masked_crc(length)) + data + struct.pack("<I", masked_crc(data))


def tensorboard_events(metrics: Iterable[tuple[int, str, float, float]]) -> bytes:
    """An events.out.tfevents file of scalar summaries from (step, name, value, wall_time) rows."""
    out = [_record(_event(time.time(), 0, file_version="brain.Event:2"))]
    for step, name, value, wall_time in metrics:
        out.append(_record(_event(wall_time, step, scalars={name: value})))
    return b"".join(out)


def read_tensorboard_scalars(data: bytes) -> list[tuple[int, str, float]]:
    """Read back the scalars of an event file written above, checking every CRC (for tests and for users who
    want to check a download without TensorBoard)."""
    scalars: list[tuple[int, str, float]] = []
    offset = 0
    while offset < len(data):
        (length,) = struct.unpack_from("<Q", data, offset)
        if struct.unpack_from("<I", data, offset + 8)[0] != masked_crc(data[offset : offset + 8]):
            raise ValueError("bad length CRC")
        record = data[offset + 12 : offset + 12 + length]
        if struct.unpack_from("<I", data, offset + 12 + length)[0] != masked_crc(record):
            raise ValueError("bad data CRC")
        offset += 16 + length
        scalars.extend(_scalars_of(record))
    return scalars


def _read_varint(data: bytes, offset: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        byte = data[offset]
        offset += 1
        value |= (byte & 0x7F) << shift
        shift += 7
        if not byte & 0x80:
            return value, offset


def _fields(data: bytes) -> Iterator[tuple[int, int, object]]:
    offset = 0
    while offset < len(data):
        key, offset = _read_varint(data, offset)
        number, wire = key >> 3, key & 7
        if wire == 0:
            value, offset = _read_varint(data, offset)
        elif wire == 1:
            value, offset = data[offset : offset + 8], offset + 8
        elif wire == 5:
            value, offset = data[offset : offset + 4], offset + 4
        else:
            length, offset = _read_varint(data, offset)
            value, offset = data[offset : offset + length], offset + length
        yield number, wire, value


def _scalars_of(event: bytes) -> list[tuple[int, str, float]]:
    step, found = 0, []
    for number, _wire, value in _fields(event):
        if number == 2:
            step = int(value)  # type: ignore[arg-type]
        elif number == 5:
            for _n, _w, summary_value in _fields(value):  # type: ignore[arg-type]
                parts = {n: v for n, _w2, v in _fields(summary_value)}  # type: ignore[arg-type]
                found.append((step, parts[1].decode(), struct.unpack("<f", parts[2])[0]))  # type: ignore[union-attr]
    return found


# ---------------------------------------------------------------- the evaluation rollout as a video file
def _chunk(fourcc: bytes, payload: bytes) -> bytes:
    return fourcc + struct.pack("<I", len(payload)) + payload + (b"\0" if len(payload) % 2 else b"")


def _list(kind: bytes, payload: bytes) -> bytes:
    return _chunk(b"LIST", kind + payload)


def gif_to_avi(gif: bytes, *, quality: int = 90) -> bytes:
    """The rollout GIF as a Motion-JPEG AVI (plays in VLC, mpv, ffmpeg, video editors; Pillow only). Its frame
    rate is the GIF's first frame duration."""
    from PIL import Image, ImageSequence

    source = Image.open(io.BytesIO(gif))
    frame_ms = int(source.info.get("duration") or 80)
    jpegs = []
    for frame in ImageSequence.Iterator(source):
        buffer = io.BytesIO()
        frame.convert("RGB").save(buffer, format="JPEG", quality=quality)
        jpegs.append(buffer.getvalue())
    width, height = source.size
    count, largest = len(jpegs), max(len(jpeg) for jpeg in jpegs)
    avih = struct.pack(
        "<14I", frame_ms * 1000, largest * 1000 // max(frame_ms, 1), 0, 0x10, count, 0, 1, largest, width, height,
        0, 0, 0, 0,
    )  # fmt: skip
    strh = b"vidsMJPG" + struct.pack("<IHHIIIIIIIIhhhh", 0, 0, 0, 0, frame_ms, 1000, 0, count, largest, 10000, 0,
                                     0, 0, width, height)  # fmt: skip
    strf = struct.pack("<IiiHH4sIiiII", 40, width, height, 1, 24, b"MJPG", width * height * 3, 0, 0, 0, 0)
    header = _list(b"hdrl", _chunk(b"avih", avih) + _list(b"strl", _chunk(b"strh", strh) + _chunk(b"strf", strf)))
    frames, index, offset = [], [], 4  # offsets count from the 'movi' fourcc
    for jpeg in jpegs:
        chunk = _chunk(b"00dc", jpeg)
        index.append(b"00dc" + struct.pack("<III", 0x10, offset, len(jpeg)))
        frames.append(chunk)
        offset += len(chunk)
    body = b"AVI " + header + _list(b"movi", b"".join(frames)) + _chunk(b"idx1", b"".join(index))
    return b"RIFF" + struct.pack("<I", len(body)) + body
