"""The XML side of the CommonRoad reader: parsing with line numbers, located errors, values and shapes.

``XmlDoc`` remembers the line each element starts on and its parent (ElementTree does neither), so
every message names the file, the line, the element and its id, or for an element without one (a
point's ``<x>``) the nearest enclosing element that has one.

Only a regular file is read, and only up to :data:`MAX_FILE_BYTES`: a FIFO would block the item
forever and ``/dev/zero`` would be read until memory runs out.  Every number must be finite: a
``nan`` coordinate would otherwise surface far from the file, as a lane "width nan" or a raster.
"""
from __future__ import annotations

import math
import os
import stat
import xml.etree.ElementTree as ET
from pathlib import Path
from xml.parsers import expat

import numpy as np

from ...core.errors import display_path
from .commonroad_types import Circle, CommonRoadError, Interval, Polygon, Rectangle, Shape

__all__ = ["MAX_FILE_BYTES", "XmlDoc", "parse_xml"]

#: bytes a CommonRoad file may have: the largest benchmark files are a few MiB, and parsing takes
#: 10 to 40 times a file's size in memory (measured with tracemalloc), so 128 MiB needs up to ~5 GiB
MAX_FILE_BYTES = 128 * 2 ** 20


class XmlDoc:
    """The parsed file and where each element started, for messages."""

    def __init__(self, path: Path):
        self.path = path
        self.lines: dict[ET.Element, int] = {}
        self.parents: dict[ET.Element, ET.Element] = {}

    def error(self, element: ET.Element | None, message: str) -> CommonRoadError:
        if element is None:
            return CommonRoadError(f"{display_path(self.path)}: {message}")
        line = self.lines.get(element)
        where = f"{display_path(self.path)}:{line}" if line else display_path(self.path)
        return CommonRoadError(f"{where}: {self._describe(element)}: {message}")

    def _describe(self, element: ET.Element) -> str:
        """``<lanelet id="7">``; an element without an id within the nearest one that has one."""
        ident = element.get("id")
        if ident is not None:
            return f'<{element.tag} id="{ident}">'
        owner = self.parents.get(element)
        while owner is not None and owner.get("id") is None:
            owner = self.parents.get(owner)
        return f"<{element.tag}>" + (f' in <{owner.tag} id="{owner.get("id")}">' if owner is not None else "")

    def number(self, element: ET.Element, text: str | None, what: str, infinite: bool = False) -> float:
        """The element's number; nan is refused, and so is an infinity unless ``infinite`` (an
        interval's open end)."""
        try:
            value = float(text)
        except (TypeError, ValueError):
            raise self.error(element, f"{what}: expected a number, got {text!r}") from None
        if math.isnan(value) or (math.isinf(value) and not infinite):
            raise self.error(element, f"{what}: expected a finite number, got {text.strip()!r}: "
                                      "give the value this element stands for")
        return value

    def ident(self, node: ET.Element) -> int:
        try:
            return int(node.get("id"))
        except (TypeError, ValueError):
            raise self.error(node, f"id: expected an integer, got {node.get('id')!r}") from None

    def child_number(self, node: ET.Element, tag: str, infinite: bool = False) -> float:
        child = node.find(tag)
        if child is None:
            raise self.error(node, f"<{tag}> missing")
        return self.number(child, child.text, tag, infinite)

    def value(self, node: ET.Element | None, owner: ET.Element, exact: bool):
        """``<exact>`` as a float, ``<intervalStart>/<intervalEnd>`` as an Interval (an error where ``exact``)."""
        if node is None:
            return None
        if node.find("exact") is not None:
            value = self.child_number(node, "exact")
            return value if exact else Interval(value, value)
        if node.find("intervalStart") is not None or node.find("intervalEnd") is not None:
            if exact:
                raise self.error(owner, f"<{node.tag}> holds an interval where an exact value is needed")
            interval = Interval(self.child_number(node, "intervalStart", infinite=True),
                                self.child_number(node, "intervalEnd", infinite=True))
            if not interval.start <= interval.end:
                raise self.error(owner, f"<{node.tag}> interval starts at {interval.start}, after its end {interval.end}")
            return interval
        raise self.error(owner, f"<{node.tag}> holds neither <exact> nor <intervalStart>/<intervalEnd>")

    def points(self, node: ET.Element | None, owner: ET.Element, what: str) -> np.ndarray:
        if node is None:
            raise self.error(owner, f"<{what}> missing")
        points = node.findall("point")
        return np.array([[self.child_number(p, "x"), self.child_number(p, "y")] for p in points],
                        dtype=np.float64).reshape(len(points), 2)

    def center(self, node: ET.Element) -> np.ndarray:
        c = node.find("center")
        return np.zeros(2) if c is None else np.array([self.child_number(c, "x"), self.child_number(c, "y")])

    def shapes(self, node: ET.Element) -> list[Shape]:
        shapes: list[Shape] = []
        for child in node:
            if child.tag == "rectangle":
                o = child.find("orientation")
                shapes.append(Rectangle(self.child_number(child, "length"), self.child_number(child, "width"),
                                        self.center(child),
                                        0.0 if o is None else self.number(o, o.text, "orientation")))
            elif child.tag == "circle":
                shapes.append(Circle(self.child_number(child, "radius"), self.center(child)))
            elif child.tag == "polygon":
                vertices = self.points(child, child, "polygon")
                if len(vertices) > 1 and np.array_equal(vertices[0], vertices[-1]):
                    vertices = vertices[:-1]
                if len(vertices) < 3:
                    raise self.error(child, f"polygon with {len(vertices)} distinct vertices")
                shapes.append(Polygon(vertices))
        return shapes


def parse_xml(path: Path) -> tuple[ET.Element, XmlDoc]:
    """The root element and the document's line table; expat resolves no external entities and loads no DTD."""
    doc = XmlDoc(path)
    data = _read_bounded(path, doc)
    builder = ET.TreeBuilder()
    parser = expat.ParserCreate()
    parser.buffer_text = True
    open_elements: list[ET.Element] = []

    def start(tag, attrs):
        element = builder.start(tag, attrs)
        doc.lines[element] = parser.CurrentLineNumber
        if open_elements:
            doc.parents[element] = open_elements[-1]
        open_elements.append(element)

    def end(tag):
        open_elements.pop()
        builder.end(tag)

    parser.StartElementHandler = start
    parser.EndElementHandler = end
    parser.CharacterDataHandler = builder.data
    try:
        parser.Parse(data, True)
    except expat.ExpatError as exc:
        raise doc.error(None, f"not XML: {expat.ErrorString(exc.code)} at line {exc.lineno}") from None
    return builder.close(), doc


def _kind(mode: int) -> str:
    for test, name in ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "not a regular file"


def _read_bounded(path: Path, doc: XmlDoc) -> bytes:
    """The file's bytes: a regular file of at most MAX_FILE_BYTES, else a CommonRoadError."""
    try:
        # O_NONBLOCK: opening a FIFO for reading would otherwise wait for a writer, forever.
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except OSError as exc:
        raise doc.error(None, f"cannot read: {exc.strerror or exc}") from None
    limit = f"the {MAX_FILE_BYTES // 2 ** 20} MiB a CommonRoad file may have here"
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise doc.error(None, f"is {_kind(info.st_mode)}, not a CommonRoad XML file: name the scenario's "
                                  ".xml file itself")
        if info.st_size > MAX_FILE_BYTES:
            raise doc.error(None, f"is {info.st_size / 2 ** 20:.1f} MiB, more than {limit} (benchmark scenarios "
                                  "are a few MiB; parsing takes up to 40 times a file's size in memory): check "
                                  "that this is the scenario file you meant, or cut the map down")
        with os.fdopen(fd, "rb", closefd=False) as handle:
            data = handle.read(MAX_FILE_BYTES + 1)  # a file that grows while read is still bounded
    except OSError as exc:
        raise doc.error(None, f"cannot read: {exc.strerror or exc}") from None
    finally:
        os.close(fd)
    if len(data) > MAX_FILE_BYTES:
        raise doc.error(None, f"grew to more than {limit} while it was read")
    return data
