"""Learning curves: a run's table of values per step, written as Parquet (through the store)
and mirrored as TensorBoard event files (tensorboardX, the writer Ray Tune's
``TBXLoggerCallback`` uses), so that ``tensorboard --logdir runs`` shows every run below it.

The table is the record; the event files are rewritten whole from it at every write (a run
that resumes after a kill rewrites them too, so no step appears twice). No Ray.
"""

from __future__ import annotations

import math
import os
import struct
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pandas as pd

EVENTS_GLOB = "events.out.tfevents.*"
"""How TensorBoard recognises an event file (the prefix tensorboardX writes)."""


def scalar_columns(table: pd.DataFrame, step: str) -> list[str]:
    """The columns of ``table`` that become TensorBoard scalars: numeric or boolean, not
    ``step``.

    >>> scalar_columns(pd.DataFrame({"batch": [1], "loss": [0.5], "note": ["x"]}), "batch")
    ['loss']
    """
    return [
        c
        for c in table.columns
        if c != step
        and (pd.api.types.is_numeric_dtype(table[c]) or pd.api.types.is_bool_dtype(table[c]))
    ]


def table_scalars(table: pd.DataFrame, step: str, prefix: str) -> pd.DataFrame:
    """``table``'s scalar columns as rows ``tag`` (``prefix/column``), ``step`` (column
    ``step``), ``value``, in row order, NaN values left out.

    >>> t = pd.DataFrame({"batch": [1, 2], "loss": [0.5, float("nan")]})
    >>> table_scalars(t, "batch", "bc").values.tolist()
    [['bc/loss', 1, 0.5]]
    """
    columns = scalar_columns(table, step)
    rows = []
    for values in table.to_dict(orient="records"):  # any column name, "lambda" too
        at = int(values[step])
        for c in columns:
            v = float(values[c])
            if math.isfinite(v):
                rows.append((f"{prefix}/{c}", at, v))
    return pd.DataFrame(rows, columns=["tag", "step", "value"])


def write_scalars(
    logdir: str | Path,
    scalars: pd.DataFrame,
    hparams: tuple[dict[str, Any], dict[str, float]] | None = None,
) -> Path:
    """Write the rows ``tag``, ``step``, ``value`` of ``scalars`` as TensorBoard scalars (and,
    with ``hparams`` ``(settings, metrics)``, one entry of TensorBoard's HParams view; the
    metrics must be among the scalars) into one event file in ``logdir``, replacing the event
    files there. The new file is written in a temporary folder inside ``logdir`` and moved in
    before the old ones are removed. Returns the file's path."""
    from tensorboardX import SummaryWriter

    logdir = Path(logdir)
    logdir.mkdir(parents=True, exist_ok=True)
    old = sorted(logdir.glob(EVENTS_GLOB))
    with tempfile.TemporaryDirectory(dir=logdir, prefix=".events-") as tmp:
        writer = SummaryWriter(logdir=tmp, flush_secs=3600)
        try:
            if hparams is not None:
                from tensorboardX.summary import hparams as hparams_summaries

                for summary in hparams_summaries(*hparams):  # experiment, session start, end
                    writer.file_writer.add_summary(summary)
            for tag, at, v in scalars[["tag", "step", "value"]].itertuples(index=False):
                writer.add_scalar(str(tag), float(v), global_step=int(at))
        finally:
            writer.close()
        (written,) = Path(tmp).glob(EVENTS_GLOB)
        target = logdir / written.name
        if target in old:  # the same second and host: keep the names apart
            target = logdir / f"{written.name}.{os.getpid()}"
        with open(written, "rb") as f:
            os.fsync(f.fileno())
        os.replace(written, target)
    for path in old:
        if path != target:
            path.unlink(missing_ok=True)
    return target


def write_events(logdir: str | Path, table: pd.DataFrame, step: str, prefix: str) -> Path:
    """Write ``table``'s scalar columns as TensorBoard scalars ``prefix/column`` at the steps of
    column ``step`` (NaN values left out) into one event file in ``logdir``, replacing the
    event files there (:func:`write_scalars`). Returns the file's path."""
    return write_scalars(logdir, table_scalars(table, step, prefix))


def write_curve(
    path: str | Path,
    table: pd.DataFrame,
    step: str,
    prefix: str,
    metadata: dict[str, Any] | None = None,
) -> Path:
    """The curve ``table`` (one row per ``step``) as the Parquet table ``path`` (with
    ``metadata``) and as TensorBoard scalars ``prefix/column`` in event files beside it."""
    from safe_bc.data.store import write_table_atomic

    path = Path(path)
    write_table_atomic(path, table, metadata)
    write_events(path.parent, table, step, prefix)
    return path


def _records(path: Path) -> Iterator[bytes]:
    """The records of a TFRecord file (TensorBoard's event file framing), CRCs checked."""
    from tensorboardX.record_writer import masked_crc32c

    data = path.read_bytes()
    at = 0
    while at < len(data):
        if len(data) - at < 12:
            raise ValueError(f"{path}: truncated record header at byte {at}")
        header = data[at : at + 8]
        (length,) = struct.unpack("<Q", header)
        (crc,) = struct.unpack("<I", data[at + 8 : at + 12])
        if crc != masked_crc32c(header):
            raise ValueError(f"{path}: corrupt record header at byte {at}")
        body = data[at + 12 : at + 12 + length]
        (body_crc,) = struct.unpack("<I", data[at + 12 + length : at + 16 + length])
        if len(body) != length or body_crc != masked_crc32c(body):
            raise ValueError(f"{path}: corrupt record at byte {at}")
        yield body
        at += 16 + length


def read_events(logdir: str | Path) -> pd.DataFrame:
    """The scalars of the event files directly in ``logdir``: columns ``tag``, ``step``,
    ``value``, in file and write order (tensorboardX's protobuf; no TensorBoard needed)."""
    from tensorboardX.proto.event_pb2 import Event

    rows: list[tuple[str, int, float]] = []
    for path in sorted(Path(logdir).glob(EVENTS_GLOB)):
        for record in _records(path):
            event = Event.FromString(record)
            for value in event.summary.value:
                scalar = value.simple_value
                if value.HasField("tensor") and value.tensor.float_val:
                    scalar = value.tensor.float_val[0]
                rows.append((value.tag, int(event.step), float(scalar)))
    return pd.DataFrame(rows, columns=["tag", "step", "value"])


def read_hparams(logdir: str | Path) -> dict[str, Any]:
    """The settings of the HParams entry in the event files directly in ``logdir`` (TensorBoard's
    session start info: name -> bool, number or text; ``{}``: none), without TensorBoard."""
    from tensorboardX.proto.event_pb2 import Event
    from tensorboardX.proto.plugin_hparams_pb2 import HParamsPluginData

    out: dict[str, Any] = {}
    for path in sorted(Path(logdir).glob(EVENTS_GLOB)):
        for record in _records(path):
            for value in Event.FromString(record).summary.value:
                if value.metadata.plugin_data.plugin_name != "hparams":
                    continue
                data = HParamsPluginData.FromString(value.metadata.plugin_data.content)
                if not data.HasField("session_start_info"):
                    continue
                for name, v in data.session_start_info.hparams.items():
                    kind = v.WhichOneof("kind")
                    out[name] = getattr(v, kind) if kind else None
    return out
