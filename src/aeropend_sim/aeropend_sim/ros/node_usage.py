"""What a node is, reads, writes and takes: the declarative tables behind ``<node> --help``.

Every node declares its ROS parameters in one table of :class:`NodeParameter` (name, type,
default, unit, description, live or read-only) and its topics as :class:`TopicUse` rows (names
and message types from :mod:`aeropend_sim.contract`). The node's parameter declaration
(:func:`aeropend_sim.ros.node_shell.declare_parameter_table`) and its usage text
(:meth:`NodeUsage.text`, printed by ``-h`` / ``--help``) read the same table, so the two cannot
drift apart. This module imports no rclpy: ``--help`` answers without starting ROS.
"""

from __future__ import annotations

import argparse
import textwrap
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

from aeropend_sim.contract import CONTRACT_TOPICS, TOPIC_CLOCK, TYPE_CLOCK

#: Width of the usage text (the description column wraps at it).
WIDTH = 100


class NodeParameter(NamedTuple):
    """One ROS parameter of a node.

    Attributes
    ----------
    name : str
        Parameter name (``-p name:=value``).
    type : str
        Expected type as a reader would write it: ``str``, ``int``, ``float``, ``bool``,
        ``str[]``, ``float[]`` (parameters are declared dynamically typed and validated by the
        node, so this is documentation and the node's validation is the check).
    default : Any
        Value when not given; ``None`` = unset (the description says what that means).
    unit : str
        SI unit of the value ("" for a name, a count or a dimensionless number).
    description : str
        What it does (one sentence or a few; wrapped in the usage text).
    live : bool
        True if ``ros2 param set`` may change it while the node runs; otherwise it is declared
        read-only (fixed at start-up).
    """

    name: str
    type: str
    default: Any
    unit: str
    description: str
    live: bool = False

    def declared_description(self) -> str:
        """Description stored in the parameter's ROS descriptor (``ros2 param describe``)."""
        unit = f" [{self.unit}]" if self.unit else ""
        fixed = "" if self.live else " (read-only: fixed at start-up)"
        return f"{self.description}{unit} ({self.type}){fixed}"


class TopicUse(NamedTuple):
    """A topic a node publishes or subscribes.

    Attributes
    ----------
    direction : str
        ``publishes`` or ``subscribes``.
    name : str
        Topic name; relative names (no leading ``/``) resolve in the node's namespace.
    type : str
        Message type (``pkg/msg/Type``).
    note : str
        When or how (e.g. "lockstep mode only").
    """

    direction: str
    name: str
    type: str
    note: str = ""


def contract_topic(direction: str, name: str, note: str = "") -> TopicUse:
    """A contract topic (``REL_*``/``TOPIC_*`` of :mod:`aeropend_sim.contract`) with its contract type.

    Raises
    ------
    KeyError
        If ``name`` is not a contract topic (a node's own topic gives its type itself).
    """
    if name == TOPIC_CLOCK:
        return TopicUse(direction, name, TYPE_CLOCK, note)
    return TopicUse(direction, name, CONTRACT_TOPICS["/" + name.lstrip("/")], note)


def _default_text(p: NodeParameter) -> str:
    if p.default is None:
        return "unset"
    if isinstance(p.default, bool):
        return str(p.default).lower()
    if isinstance(p.default, str):
        return repr(p.default) if p.default == "" else p.default
    if isinstance(p.default, (list, tuple)):
        return "[" + ", ".join(repr(x) if isinstance(x, str) else str(x) for x in p.default) + "]"
    return str(p.default)


def strip_ros_args(argv: Sequence[str]) -> list[str]:
    """``argv`` without its ``--ros-args ... [--]`` sections (what the node's own parser sees)."""
    out: list[str] = []
    in_ros = False
    for tok in argv:
        if tok == "--ros-args":
            in_ros = True
        elif tok == "--" and in_ros:
            in_ros = False
        elif not in_ros:
            out.append(tok)
    return out


@dataclass(frozen=True)
class NodeUsage:
    """Usage of a node's console script: what it does, its topics, parameters and an example.

    Attributes
    ----------
    command : str
        Console script (``sim_node``).
    node_name : str
        Default ROS node name (``aeropend_sim``).
    summary : str
        What the node does (a paragraph).
    topics : tuple of TopicUse
        Topics it publishes and subscribes.
    parameters : tuple of NodeParameter
        Its ROS parameters (the table the node declares).
    examples : tuple of str
        Command lines shown under "Examples".
    notes : str
        Closing paragraph (exit status, live-parameter rules, ...).
    """

    command: str
    node_name: str
    summary: str
    topics: tuple[TopicUse, ...]
    parameters: tuple[NodeParameter, ...]
    examples: tuple[str, ...]
    notes: str = ""

    def parameter_lines(self) -> list[str]:
        """The "Parameters" section: one entry per parameter, description indented below."""
        if not self.parameters:
            return []
        lines = textwrap.wrap("ROS parameters (--ros-args -p NAME:=VALUE; 'live' ones can be changed with "
                              "`ros2 param set` while the node runs, the others are read-only):", WIDTH)
        for p in self.parameters:
            unit = f" [{p.unit}]" if p.unit else ""
            lines.append(f"  {p.name} ({p.type}{unit}) = {_default_text(p)}    "
                         f"{'live' if p.live else 'read-only'}")
            lines += textwrap.wrap(p.description, WIDTH, initial_indent=" " * 6, subsequent_indent=" " * 6)
        return lines

    def topic_lines(self) -> list[str]:
        """The "Topics" section (relative names resolve in the node's namespace, ``-r __ns:=/rig2``)."""
        if not self.topics:
            return []
        lines = textwrap.wrap(f"Topics of node {self.node_name} (relative names resolve in its namespace: "
                              "-r __ns:=/rig2 gives /rig2/aeropend/...):", WIDTH)
        for t in self.topics:
            lines.append(f"  {t.direction} {t.name} ({t.type})")
            lines += textwrap.wrap(t.note, WIDTH, initial_indent=" " * 6, subsequent_indent=" " * 6)
        return lines

    def epilog(self) -> str:
        """Topics, parameters, examples and notes: the part of ``--help`` after the flags."""
        parts = [self.topic_lines(), self.parameter_lines(),
                 ["Examples:", *(f"  {e}" for e in self.examples)] if self.examples else []]
        text = "\n\n".join("\n".join(p) for p in parts if p)
        if self.notes:
            text += "\n\n" + textwrap.fill(self.notes, WIDTH)
        return text

    def parser(self, **kwargs: Any) -> argparse.ArgumentParser:
        """An argument parser whose ``--help`` prints this usage (add the node's own flags to it).

        Keyword arguments go to :class:`argparse.ArgumentParser` (e.g. ``usage``).
        """
        return argparse.ArgumentParser(
            prog=self.command, description=textwrap.fill(self.summary, WIDTH), epilog=self.epilog(),
            formatter_class=argparse.RawDescriptionHelpFormatter, **kwargs)

    def text(self) -> str:
        """The whole ``--help`` text of a node without command-line flags of its own."""
        return self.parser().format_help()
