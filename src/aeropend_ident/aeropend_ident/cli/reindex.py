"""Rebuild a bag's ``metadata.yaml`` from its storage files: ``reindex BAG_DIR [--overwrite] [--repair NEW]``.

Command line of ``reindex`` (console script; ``ros2 run aeropend_ident reindex``), the
counterpart of ``ros2 bag reindex`` for machines without the ``ros2`` CLI: a recorder that was
killed leaves its bag directory without ``metadata.yaml``, and rosbag2 tools (and every aeropend
command) need it. The metadata is rebuilt by :func:`aeropend_ident.io.bag_recover.reindex`; a
storage file cut short is indexed with the messages that can be recovered from it (a warning
says how many and where the file ends); a corrupt chunk (CRC mismatch, unreadable record) is left
out and every intact one around it kept (a warning per part: its byte range, log times and the
messages it held); an empty storage file is reported as "empty: nothing was written". When the
recorder stored no loss count (it was killed before it closed the bag), the loss per topic is
counted from the header stamps, printed and stored in the metadata, where every reader finds it.
``--repair NEW_BAG_DIR`` also writes a clean copy of every recoverable message
(:func:`aeropend_ident.io.bag_repair.repair`), which tools that stop at a corrupt chunk
(``ros2 bag play``) read whole.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from collections.abc import Sequence
from pathlib import Path

from aeropend_ident.errors import BagError, BagTruncatedWarning, print_warnings_as_lines
from aeropend_ident.io.bag_recover import REINDEX_LOSS_NOTE, reindex
from aeropend_ident.io.bag_repair import repair
from aeropend_ident.io.integrity.loss import loss_text, stored_loss


def build_parser() -> argparse.ArgumentParser:
    """Argument parser of the ``reindex`` command."""
    p = argparse.ArgumentParser(
        prog="reindex",
        description="Rebuild a rosbag2 bag directory's metadata.yaml from its .mcap/.db3 storage files "
                    "(like 'ros2 bag reindex').",
    )
    p.add_argument("bag", type=Path, metavar="BAG_DIR", help="bag directory holding the storage file(s)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing metadata.yaml")
    p.add_argument("--repair", type=Path, metavar="NEW_BAG_DIR",
                   help="also write a clean copy of every recoverable message to a new bag directory "
                        "(the damaged parts left out), which any rosbag2 tool can play; the original "
                        "is not changed")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Console script ``reindex``: writes ``BAG_DIR/metadata.yaml``, prints what it indexed."""
    args = build_parser().parse_args(argv)
    print_warnings_as_lines("reindex")
    try:
        # --repair copies the messages of this one validated read
        target, info, scans = reindex(args.bag, overwrite=args.overwrite,
                                      keep_messages=args.repair is not None)
    except BagError as exc:
        print(f"reindex: error: {exc}", file=sys.stderr)
        return 1
    for s in scans:
        if s.truncated:
            warnings.warn(f"{s.path} is truncated: {s.where_it_ends()}; indexed the {s.total} message(s) "
                          "that can be recovered", BagTruncatedWarning, stacklevel=1)
        for k in s.skipped:
            warnings.warn(f"{s.path}: left out a corrupt part, {k.describe(s.t0_ns)}; the {s.total} "
                          "intact message(s) around it are indexed", BagTruncatedWarning, stacklevel=1)
    topics = ", ".join(f"{t['topic_metadata']['name']} {t['message_count']}"
                       for t in info["topics_with_message_count"])
    print(f"reindex: wrote {target}: {info['message_count']} message(s) in {len(scans)} "
          f"{info['storage_identifier']} file(s) over {info['duration']['nanoseconds'] / 1e9:.3f} s"
          f" ({topics or 'no topics'})")
    loss = stored_loss(info.get("custom_data") or {})
    if loss and any(r.get("note") == REINDEX_LOSS_NOTE for r in loss.values()):
        print(f"reindex: loss: {loss_text(loss)} ({REINDEX_LOSS_NOTE})")
    if args.repair is not None:
        try:
            out, written, _ = repair(args.bag, args.repair, rebuilt=(info, scans))
        except BagError as exc:
            print(f"reindex: error: {exc}", file=sys.stderr)
            return 1
        print(f"reindex: wrote the repaired bag {out}: {written} message(s), the damaged parts left out "
              f"({args.bag} unchanged)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
