"""The XML side of the CommonRoad reader: parsing with line numbers, located errors, values and shapes.

``XmlDoc`` remembers the line each element starts on (ElementTree does not), so every message names
the file, the line, the element and its id.
"""
from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path
from xml.parsers import expat

import numpy as np

from ...core.errors import display_path
from .commonroad_types import Circle, CommonRoadError, Interval, Polygon, Rectangle, Shape

__all__ = ["XmlDoc", "parse_xml"]


class XmlDoc:
    """The parsed file and where each element started, for messages."""

    def __init__(self, path: Path):
        self.path = path
        self.lines: dict[ET.Element, int] = {}

    def error(self, element: ET.Element | None, message: str) -> CommonRoadError:
        if element is None:
            return CommonRoadError(f"{display_path(self.path)}: {message}")
        ident = f' id="{element.get("id")}"' if element.get("id") is not None else ""
        line = self.lines.get(element)
        where = f"{display_path(self.path)}:{line}" if line else display_path(self.path)
        return CommonRoadError(f"{where}: <{element.tag}{ident}>: {message}")

    def number(self, element: ET.Element, text: str | None, what: str) -> float:
        try:
            return float(text)
        except (TypeError, ValueError):
            raise self.error(element, f"{what}: expected a number, got {text!r}") from None

    def ident(self, node: ET.Element) -> int:
        try:
            return int(node.get("id"))
        except (TypeError, ValueError):
            raise self.error(node, f"id: expected an integer, got {node.get('id')!r}") from None

    def child_number(self, node: ET.Element, tag: str) -> float:
        child = node.find(tag)
        if child is None:
            raise self.error(node, f"<{tag}> missing")
        return self.number(child, child.text, tag)

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
            interval = Interval(self.child_number(node, "intervalStart"), self.child_number(node, "intervalEnd"))
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
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise doc.error(None, f"cannot read: {exc.strerror or exc}") from None
    builder = ET.TreeBuilder()
    parser = expat.ParserCreate()
    parser.buffer_text = True

    def start(tag, attrs):
        doc.lines[builder.start(tag, attrs)] = parser.CurrentLineNumber

    parser.StartElementHandler = start
    parser.EndElementHandler = builder.end
    parser.CharacterDataHandler = builder.data
    try:
        parser.Parse(data, True)
    except expat.ExpatError as exc:
        raise doc.error(None, f"not XML: {expat.ErrorString(exc.code)} at line {exc.lineno}") from None
    return builder.close(), doc
