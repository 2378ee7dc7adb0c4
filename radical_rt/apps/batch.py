"""Process MCAP archives with the calibration engine (the batch shell).

    radical process IN.mcap [IN2.mcap ...] -o OUT.mcap --summary SUMMARY.json [--cold]

Several inputs are disjoint telemetry streams processed in order: between them the engine warm
starts (attitude reset, parameter UD factors kept) and applies the configured covariance bump;
``--cold`` cold-starts every stream instead. The output archive holds the telemetry, fault and
diag channels (and a copy of the last input's ``/truth/params`` when present); the summary file is
CONTRACT §5's. The same :class:`~radical_rt.stream.processor.StreamProcessor` runs inside ``radical node``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from radical_rt.clock.siru_clock import ClockConfig, SiruClock
from radical_rt.contract.conventions import PAPER_UNITS, to_paper_units
from radical_rt.contract.paper_table import format_table, rows
from radical_rt.contract.params import ParamError, ParamTable
from radical_rt.contract.state import PARAM_GROUPS
from radical_rt.io.archive import ArchiveError, ArchiveReader, ArchiveWriter
from radical_rt.io.outpaths import OutputPathError, output_file, prepare_output
from radical_rt.stream.processor import StreamProcessor
from radical_rt.stream.telemetry import PacketError, load_packets

INPUTS = ("/siru", "/st1", "/st2", "/temp")


def make_processor(table: ParamTable | None = None, clock_mode: str = "reconstruct",
                   packets_path: str | None = None) -> StreamProcessor:
    """An engine + clock + stream processor configured as both shells use it."""
    table = table or ParamTable()
    clock = SiruClock(ClockConfig(mode=clock_mode), n_gyro=table.n_gyro)
    packets = load_packets(packets_path) if packets_path else None
    return StreamProcessor(table, clock, packets)


def process(inputs: list[str], out_path: str | None, summary_path: str | None = None, *,
            cold: bool = False, table: ParamTable | None = None, clock_mode: str = "reconstruct",
            packets_path: str | None = None, progress: bool = False) -> dict[str, Any]:
    """Run the engine over the input archives in order; return the summary (paper units).
    The output paths' parent directories are created first (OutputPathError if impossible)."""
    for path in (out_path, summary_path):
        if path:
            prepare_output(path)
    readers = [ArchiveReader(p) for p in inputs]
    for r in readers:
        r.require_inputs()
    sp = make_processor(table, clock_mode, packets_path)
    writer = ArchiveWriter(out_path, scenario={"name": "radical process", "generator": "radical-rt",
                                               "inputs": ",".join(map(str, inputs))}) if out_path else None
    total = sum(sum(r.message_counts.get(t, 0) for t in INPUTS) for r in readers)
    bar = tqdm(total=total, unit="msg", disable=not progress, file=sys.stderr, desc="process")
    truth = None
    try:
        for i, reader in enumerate(readers):
            if i > 0:
                _write(writer, sp.end_stream("cold" if cold else "warm"))
            sp.streams.source = str(inputs[i])
            for blk in reader.iter_blocks([*INPUTS, "/truth/params"]):
                _feed_block(sp, blk, writer, bar if progress else None,
                            keep_truth=i == len(readers) - 1)
                truth = _truth(blk, truth)
        _write(writer, sp.end_stream(None))
    finally:
        bar.close()
        if writer:
            writer.close()
        for r in readers:
            r.close()
    summary = make_summary(sp)
    if truth is not None:
        import msgpack
        summary["truth"] = truth_paper_units(msgpack.unpackb(truth, raw=False))
    if summary_path:
        Path(summary_path).write_text(json.dumps(summary, indent=1) + "\n")
    return summary


#: at most this many messages per StreamProcessor.feed_arrays call (its outputs are collected
#: until it returns: a bound keeps them few, and Python's cyclic collector idle)
SEGMENT = 256


def _feed_block(sp: StreamProcessor, blk, writer: ArchiveWriter | None, bar, keep_truth: bool
                ) -> None:
    """An archive block (radical_rt.io.chunk_records.Block) through the stream in segments of at
    most :data:`SEGMENT` messages; outputs written; a /truth/params message copied at its place
    (keep_truth: of the last input; segments end there), else left out."""
    names = [t[1:] for t in blk.names]  # (topics without the leading slash)
    tidx, off, size = blk.tidx, blk.off, blk.size
    cuts: list[int] = []
    if "truth/params" in names:
        is_truth = tidx == names.index("truth/params")
        if writer and keep_truth:
            cuts = [int(i) for i in np.flatnonzero(is_truth)]
        elif is_truth.any():  # nothing to copy: the stream's messages only, in order
            keep = ~is_truth
            tidx, off, size = tidx[keep], off[keep], size[keep]
    n = len(tidx)
    start = 0
    for p in [*cuts, n]:
        for a in range(start, p, SEGMENT):
            b = min(a + SEGMENT, p)
            out = sp.feed_arrays(blk.buf, names, tidx[a:b], off[a:b], size[a:b])
            if out and writer:
                _write(writer, out)
        if p < n:  # (after the outputs of what came before it)
            writer.write_raw("/truth/params", blk.payload(p), int(blk.log_ns[p]))
        start = p + 1
    if bar is not None:
        bar.update(n - len(cuts))  # (the bar counts the stream's input messages)


def _truth(blk, truth: bytes | None) -> bytes | None:
    """The last /truth/params payload of the block (else ``truth``)."""
    if "/truth/params" in blk.names:
        hits = np.flatnonzero(blk.tidx == blk.names.index("/truth/params"))
        if len(hits):
            return blk.payload(int(hits[-1]))
    return truth


def _write(writer: ArchiveWriter | None, outputs: list[tuple[str, dict]]) -> None:
    if writer is None:
        return
    for topic, msg in outputs:
        # An estimate time before bus time 0 (a tracker epoch t_bus − latency near the start of the
        # bus clock) cannot be an MCAP time; it is logged at 0 and keeps its own "t".
        writer.write("/" + topic, msg, t_bus=max(float(msg.get("t", 0.0)), 0.0))


def truth_paper_units(msg: dict) -> dict[str, list[float]]:
    return {g: [float(to_paper_units(g, v)) for v in msg[g]] for g in PARAM_GROUPS if g in msg}


def make_summary(sp: StreamProcessor) -> dict[str, Any]:
    """CONTRACT §5 summary from the final engine state, paper units."""
    e = sp.engine
    est, sig = e.estimates(), e.sigmas()
    return {"schema": "radical.summary/1", "t_end": float(e.t), "units": dict(PAPER_UNITS),
            "estimate": {g: [float(to_paper_units(g, v)) for v in est[g]] for g in PARAM_GROUPS},
            "sigma": {g: [float(to_paper_units(g, v)) for v in sig[g]] for g in PARAM_GROUPS},
            "counters": {k: v for k, v in sp.counters().items() if k in (
                "siru_samples", "siru_repeated", "siru_missing", "st1_used", "st1_edited",
                "st2_used", "st2_edited", "input_rejected")},
            "converged": e.mode == "converged", "mode": e.mode, "flags": sp.flag_names(),
            "latency_st": e.latency_estimate(),  # extension: tracker latency estimate, s
            "clock": clock_summary(sp.clock),  # extension: SIRU clock state at the end
            "streams": sp.streams.summary(e)}  # extension: per-stream records (stream_log)


def clock_summary(clock) -> dict[str, Any]:
    """The SIRU clock at the end of a run (summary extension, docs/contract_extensions.md)."""
    tel = clock.telemetry()
    keys = ("state", "note", "locked", "t_first_lock_s", "freq_offset_ppm",
            "freq_offset_sigma_ppm", "tag_error_sigma_s", "read_jitter_s")
    out = {k: tel[k] for k in keys}
    out["counters"] = {k: tel["counters"][k] for k in ("crossings", "read_glitches", "anomalies",
                                                       "relocks", "gaps", "resets")}
    return out


def clock_line(c: dict[str, Any]) -> str:
    """One line on the SIRU clock for the end of `radical process` (says so when it never
    locked)."""
    if c["state"] == "naive":
        return "SIRU clock: naive bus tags"
    sig = c["freq_offset_sigma_ppm"]
    eps = f"ε {c['freq_offset_ppm']:+.3f}" + (f" ± {sig:.3f}" if sig is not None else "") + " ppm"
    if c["t_first_lock_s"] is None:
        return f"SIRU clock: NEVER LOCKED ({c['note']}); {eps}"
    first = f"first locked at t = {c['t_first_lock_s']:.1f} s"
    now = "locked at the end" if c["locked"] else f"{c['state']} at the end ({c['note']})"
    return (f"SIRU clock: {first}, {now}; {eps}; {c['counters']['crossings']} sawtooth wraps, "
            f"{c['counters']['anomalies']} anomalies")


def summary_table(summary: dict[str, Any]) -> str:
    """The paper-style table of a summary (estimates ± σ, with truth and error/σ if known)."""
    from radical_rt.contract.conventions import from_paper_units
    si = {k: {g: [from_paper_units(g, v) for v in summary[k][g]] for g in PARAM_GROUPS}
          for k in ("estimate", "sigma")}
    truth = None
    if "truth" in summary:
        truth = {g: [from_paper_units(g, v) for v in summary["truth"][g]] for g in summary["truth"]}
    return format_table(rows(si["estimate"], si["sigma"], truth))


#: the subcommand's line in `radical --help`
HELP = "run the calibration engine over archives (batch shell)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("inputs", nargs="+", metavar="IN.mcap", help="input archives (disjoint streams, in order)")
    p.add_argument("-o", "--output", metavar="OUT.mcap", type=output_file, help="output archive (telemetry, fault, diag)")
    p.add_argument("--summary", metavar="SUMMARY.json", type=output_file, help="write the summary file here")
    p.add_argument("--cold", action="store_true", help="cold-start every stream (default: warm start + bump)")
    p.add_argument("--config", metavar="PARAMS.toml", help="parameter overrides ([params] table)")
    p.add_argument("--packets", metavar="PACKETS.toml", help="telemetry packet configuration")
    p.add_argument("--clock", choices=("reconstruct", "naive"), default="reconstruct",
                   help="SIRU time tags: online reconstruction (default) or naive bus tags")
    p.add_argument("--quiet", action="store_true", help="no progress bar and no table")
    p.set_defaults(exit_fast=True)  # every file is closed when run() returns (cli.exit_fast)


def run(args: argparse.Namespace) -> int:
    try:
        table = ParamTable.from_toml(args.config) if args.config else None
        summary = process(args.inputs, args.output, args.summary, cold=args.cold, table=table,
                          clock_mode=args.clock, packets_path=args.packets, progress=not args.quiet)
    except (ArchiveError, ParamError, PacketError, OutputPathError) as exc:
        print(f"radical process: {exc}", file=sys.stderr)
        return 2
    if not args.quiet:
        print(summary_table(summary))
        c = summary["counters"]
        print(f"mode {summary['mode']}, t_end {summary['t_end']:.2f} s; SIRU samples "
              f"{c['siru_samples']} (repeated {c['siru_repeated']}, missing {c['siru_missing']}); "
              f"ST1 used {c['st1_used']} edited {c['st1_edited']}; ST2 used {c['st2_used']} edited "
              f"{c['st2_edited']}; rejected {c['input_rejected']}")
        lat = summary["latency_st"]
        print(f"tracker latency {1e3 * lat['estimate_s']:.2f} ± {1e3 * lat['sigma_s']:.2f} ms "
              f"(configured {1e3 * lat['configured_s']:.2f} ms)")
        print(clock_line(summary["clock"]))
        for st in summary["streams"] if len(summary["streams"]) > 1 else []:
            print(stream_line(st))
    return 0


def stream_line(st: dict[str, Any]) -> str:
    """One line per stream of a multi-stream run (its end estimates are in the summary's
    ``streams``)."""
    t0, t1 = st["t_bus"]
    span = f"t_bus {t0:.2f}–{t1:.2f} s" if t0 is not None else "no input"
    bump = f" + bump ({st['bump']['mode']})" if st["bump"] else ""
    return (f"stream {st['index']} ({st['source'] or '?'}): {st['start']} start{bump}, {span}, "
            f"ended {st['mode']} at t = {st['t_end']:.2f} s")
