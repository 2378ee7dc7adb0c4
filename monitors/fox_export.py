"""Re-encode an archive for Foxglove / Lichtblick: ``radical export --foxglove IN.mcap -o OUT.mcap``.

Every channel of IN (CONTRACT §4: msgpack payloads) is written to OUT as ``json`` with a
``jsonschema`` schema of the same name (``radical.<topic>``) that Foxglove and Lichtblick can parse
(object schemas, no refs, no arrays of arrays; units in every description; see
:mod:`monitors.fox_schema`), so the Plot and Raw Message panels work on every field. Added
channels (:mod:`monitors.fox_convert`): ``/tf/body``, ``/tf/body_truth``, ``/tf/st1``,
``/tf/st2`` (``foxglove.FrameTransform``: the 3D panel shows the estimated and true attitude and
the trackers), ``/log/faults`` (``foxglove.Log``: fault-flag changes) and ``/paper/calibration``
(estimates, 1σ, truth, error/σ in deg/hr, ppm, arcsec). Values stay SI elsewhere. Log and publish
times are kept (bus time). Metadata records are copied; ``radical.export`` is added.

Two passes over IN: the first merges the shapes of the messages into the schemas (every message
of small channels; of large ones the first 2000 and every 10th after; 200 of the fixed-shape
contract channels), the second writes. Exit status 0, or 2 with a one-line error (missing file, not an MCAP archive, …).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import msgpack
from tqdm import tqdm

from monitors.fox_schema import SchemaBuilder, known_schema
from radical_rt.io.outpaths import output_file

if TYPE_CHECKING:  # (the converter imports scipy: only when the command runs, not for the parser)
    from monitors.fox_convert import FoxgloveConverter

#: topics whose shape is fixed by the contract: their schema is inferred from the first messages
_FIXED = {"/siru", "/st1", "/st2", "/temp", "/tlm/small", "/truth/attitude", "/truth/siru_time"}
_FIXED_SAMPLE = 200
#: other channels: every message up to this many, then every _STRIDE-th
_FULL_UP_TO, _STRIDE = 2000, 10


class ExportError(Exception):
    """The export cannot be made; ``str(e)`` is one line."""


def _messages(reader: Any) -> Iterator[tuple[str, int, Any]]:
    for topic, t_ns, data in reader.iter_raw():
        try:
            msg = msgpack.unpackb(data, raw=False, strict_map_key=False)
        except Exception:
            msg = None  # an undecodable payload is skipped (counted)
        yield topic, t_ns, msg


def _schema_title(topic: str) -> str:
    return "radical." + topic.lstrip("/").replace("/", ".")


def converter_for(reader: Any) -> FoxgloveConverter:
    """The converter of an archive: attitude from the fastest telemetry topic, calibration from
    the richest (so that the derived channels do not depend on channel interleaving)."""
    from monitors.fox_convert import FoxgloveConverter

    have = [t for t in ("/tlm/small", "/tlm/medium", "/tlm/large") if reader.message_counts.get(t)]
    cal = [t for t in ("/tlm/large", "/tlm/medium") if t in have]
    return FoxgloveConverter(att_topic=have[0] if have else None,
                             cal_topic=cal[0] if cal else None)


def build_schemas(reader: Any, progress: bool = False) -> dict[str, dict[str, Any]]:
    """Pass 1: topic -> JSON schema for every output topic (source channels and derived ones)."""
    from monitors.fox_convert import DERIVED_SCHEMAS, siru_known_schema

    conv = converter_for(reader)
    builders: dict[str, SchemaBuilder] = {}
    total = sum(reader.message_counts.values())
    for topic, t_ns, data in tqdm(reader.iter_raw(), total=total, desc="export: schemas",
                                  unit="msg", disable=not progress, file=sys.stderr, leave=False):
        b = builders.get(topic)
        if topic in _FIXED and b is not None and b.count >= _FIXED_SAMPLE:
            continue  # fixed shape, already sampled: not even decoded
        try:
            msg = msgpack.unpackb(data, raw=False, strict_map_key=False)
        except Exception:
            continue
        for out_topic, jm in conv.convert(topic, t_ns, msg):
            if out_topic in DERIVED_SCHEMAS:
                continue
            b = builders.get(out_topic)
            if b is None:
                known = known_schema(out_topic)
                if out_topic == "/siru":
                    known = siru_known_schema(known)
                desc = (known or {}).get("description") or f"{out_topic} messages (SI units)"
                b = builders[out_topic] = SchemaBuilder(_schema_title(out_topic), desc, known)
            n = reader.message_counts.get(topic, 0)
            if out_topic in _FIXED:
                if b.count < _FIXED_SAMPLE:
                    b.observe(jm)
            elif n <= _FULL_UP_TO or b.count < _FULL_UP_TO or b.count % _STRIDE == 0:
                b.observe(jm)  # large free-form channels: the first ones, then a sample
            else:
                b.count += 1
    schemas = {t: b.schema() for t, b in builders.items()}
    for t in reader.topics:  # channels without a decodable message still get an object schema
        if t not in schemas:
            schemas[t] = SchemaBuilder(_schema_title(t), f"{t} messages (SI units)",
                                       known_schema(t)).schema()
    return schemas


def export_foxglove(path_in: str, path_out: str, progress: bool = False) -> dict[str, Any]:
    """Write the Foxglove archive; returns {"messages": {topic: n}, "skipped": n, "path": …}."""
    from mcap.writer import CompressionType, IndexType, Writer

    from monitors.fox_convert import DERIVED_SCHEMAS
    from radical_rt.io.archive import ArchiveError, ArchiveReader

    if not os.path.exists(path_in):
        raise ExportError(f"{path_in}: no such file")
    if os.path.isdir(path_in):
        raise ExportError(f"{path_in}: is a directory, not an MCAP archive")
    if os.path.abspath(path_in) == os.path.abspath(path_out):
        raise ExportError(f"{path_out}: the output must not overwrite the input")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            reader = ArchiveReader(path_in)
    except ArchiveError as e:
        raise ExportError(str(e)) from None
    counts: dict[str, int] = {}
    skipped = 0
    tmp = path_out + ".tmp"
    try:
        with reader:
            schemas = build_schemas(reader, progress)
            try:
                Path(path_out).parent.mkdir(parents=True, exist_ok=True)
                f = open(tmp, "wb")
            except OSError as e:
                raise ExportError(f"{path_out}: cannot create: {e.strerror or e}") from None
            with f:
                w = Writer(f, compression=CompressionType.ZSTD, index_types=IndexType.ALL,
                           enable_crcs=True)
                w.start(profile="", library="radical-rt export --foxglove")
                for md in reader.metadata_records:
                    w.add_metadata(md.name, dict(md.metadata))
                w.add_metadata("radical.export", {
                    "source": os.path.abspath(path_in), "format": "foxglove json+jsonschema",
                    "units": "SI (rad, rad/s, s) except /paper/calibration (deg/hr, ppm, "
                             "arcsec) and names ending _ppm, _C, _ms",
                    "created_unix_s": f"{time.time():.0f}"})
                channels: dict[str, int] = {}

                def channel(topic: str) -> int:
                    cid = channels.get(topic)
                    if cid is None:
                        name, sch = DERIVED_SCHEMAS.get(topic) or (_schema_title(topic),
                                                                   schemas[topic])
                        sid = w.register_schema(name, "jsonschema",
                                                json.dumps(sch, sort_keys=True).encode())
                        cid = channels[topic] = w.register_channel(topic, "json", sid)
                    return cid

                for t in reader.topics:  # source channels first, in the archive's order
                    channel(t)
                conv = converter_for(reader)
                seq: dict[int, int] = {}
                total = sum(reader.message_counts.values())
                for topic, t_ns, msg in tqdm(_messages(reader), total=total, unit="msg",
                                             desc="export: write", disable=not progress,
                                             file=sys.stderr, leave=False):
                    if msg is None:
                        skipped += 1
                        continue
                    for out_topic, jm in conv.convert(topic, t_ns, msg):
                        cid = channel(out_topic)
                        n = seq.get(cid, 0)
                        seq[cid] = n + 1
                        w.add_message(cid, log_time=t_ns, publish_time=t_ns, sequence=n,
                                      data=json.dumps(jm, separators=(",", ":"),
                                                      allow_nan=False).encode())
                        counts[out_topic] = counts.get(out_topic, 0) + 1
                w.finish()
            os.replace(tmp, path_out)
    except ArchiveError as e:
        raise ExportError(str(e)) from None
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
    return {"path": path_out, "messages": dict(sorted(counts.items())), "skipped": skipped}


#: the subcommand's line in `radical --help`
HELP = "re-encode an archive for Foxglove / Lichtblick (json)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", metavar="IN.mcap", help="any RADICAL-RT archive (input or output)")
    p.add_argument("-o", "--out", "--output", dest="out", required=True, metavar="OUT.mcap",
                   type=output_file,
                   help="the archive to write")
    p.add_argument("--foxglove", action="store_true",
                   help="json + jsonschema for Foxglove / Lichtblick (the only format so far)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    if not args.foxglove:
        print("radical export: choose a format: --foxglove", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    try:
        res = export_foxglove(args.input, args.out, progress=not args.quiet)
    except ExportError as e:
        print(f"radical export: {e}", file=sys.stderr)
        return 2
    n = sum(res["messages"].values())
    extra = f", {res['skipped']} undecodable skipped" if res["skipped"] else ""
    print(f"radical export: {res['path']}: {n} messages on {len(res['messages'])} channels"
          f"{extra} ({time.perf_counter() - t0:.1f} s)")
    return 0
