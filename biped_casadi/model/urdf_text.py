"""Reading a URDF file's text for :mod:`.urdf`: the parser's robot, and what it would
misread refused or rewritten first: a xacro file (macros, ``${...}`` substitutions), a
file without links (a fragment a xacro file includes), and top-level ``<frame>``
elements (Drake's and FROST's extension) as massless links fixed to their links; the
appearance (``<material>``: colours, textures), which the model does not read, and a
default XML namespace are left out before parsing, as ROS's own parser passes over what
this one refuses in them."""
from __future__ import annotations

import re
import xml.etree.ElementTree as ET

from urdf_parser_py import urdf as _urdf
from urdf_parser_py.xml_reflection import core as _xml_core

__all__ = ["xacro_refusal"]


#: an XML declaration ``<?xml version="1.0" ...?>`` (not ``<?xml-stylesheet ...?>``)
_XML_DECLARATION = re.compile(r"<\?xml\s[^>]*\?>")

#: the namespaces a xacro file declares for its macros
_XACRO_NS = ("http://www.ros.org/wiki/xacro", "http://ros.org/wiki/xacro")


def xacro_refusal(name: str) -> str:
    """What to do with a xacro file (the refusal's advice): expand it to a URDF first.

    Parameters
    ----------
    name : str
        The xacro file's name, as the command to run names it.

    Returns
    -------
    str
        The advice, ending a refusal's line.
    """
    return (f"expand it to a URDF first ('xacro {name} > robot.urdf', with ROS's xacro or "
            f"'pip install xacro') and import robot.urdf")


def _xacro_marker(text: str) -> str | None:
    """The first xacro macro element or substitution in ``text`` (a xacro file saved
    as .urdf), or None: the URDF parser would read it as links without their macros."""
    try:
        root = ET.fromstring(text)
    except ET.ParseError:
        m = re.search(r"<xacro:[A-Za-z_]+", text)      # a prefix without its namespace
        return m.group(0) + ">" if m else None
    for el in root.iter():
        tag = el.tag if isinstance(el.tag, str) else ""
        if tag.startswith("{") and tag[1:].split("}")[0].rstrip("#/") in _XACRO_NS:
            return f"<xacro:{tag.split('}', 1)[1]}>"
        for key, value in el.attrib.items():
            if "${" in value or "$(" in value:
                return f'{key}="{value}"'
    return None


def _frames_as_links(root) -> list:
    """Each top-level ``<frame name= link= xyz= rpy=/>`` of the tree ``root`` (an
    extension of Drake's and FROST's files: contact points, soles) rewritten as a
    massless link fixed to its link, so that it can mark the foot; the notes saying so."""
    frames = [f for f in root.findall("frame") if f.get("name") and f.get("link")]
    names = {el.get("name") for el in root if el.tag in ("link", "joint")}
    done = []
    for f in frames:
        name = f.get("name")
        if name in names or f"{name}__frame" in names:
            continue
        root.remove(f)
        link = ET.SubElement(root, "link", name=name)
        link.tail = "\n"
        joint = ET.SubElement(root, "joint", name=f"{name}__frame", type="fixed")
        ET.SubElement(joint, "parent", link=f.get("link"))
        ET.SubElement(joint, "child", link=name)
        ET.SubElement(joint, "origin", xyz=f.get("xyz", "0 0 0"), rpy=f.get("rpy", "0 0 0"))
        names.add(name)
        done.append(f"{name!r} on {f.get('link')!r}")
    return [f"read the <frame> elements {', '.join(done)} as massless links fixed to their "
            f"links (Drake's and FROST's extension)"] if done else []


def _without_appearance(root) -> bool:
    """Remove the ``<material>`` elements (top-level and in visuals) of the tree ``root``:
    colours and textures, which no model quantity reads.  ``urdf_parser_py`` refuses a
    ``<texture/>`` without a file name or a colour without four numbers, which ROS's C++
    parser (and Pinocchio) pass over: the iCub of example-robot-data writes such
    textures.  Whether any was removed."""
    found = [(p, m) for p in [root, *root.findall("link/visual")] for m in p.findall("material")]
    for parent, material in found:
        parent.remove(material)
    return bool(found)


def _without_default_namespace(root) -> bool:
    """Give the elements of the tree ``root`` in its default namespace their plain names
    (``xmlns="http://drake.mit.edu"`` of Drake's older files: ``urdf_parser_py`` would
    find no ``<link>`` in it, where ROS's parser and Drake's read the names as written).
    Whether there was one."""
    if not root.tag.startswith("{"):
        return False
    ns = root.tag[:root.tag.index("}") + 1]
    for el in root.iter():
        if isinstance(el.tag, str) and el.tag.startswith(ns):
            el.tag = el.tag[len(ns):]
    return True


def _rewritten(text: str) -> tuple:
    """(text, notes): the file as ``urdf_parser_py`` reads it the way ROS's parser does
    (:func:`_without_default_namespace`, :func:`_without_appearance`,
    :func:`_frames_as_links`); the text as it was when nothing changes."""
    try:
        root = ET.fromstring(text)
    except ET.ParseError:
        return text, []
    changed = _without_default_namespace(root)
    changed = _without_appearance(root) or changed
    notes = _frames_as_links(root)
    if not (changed or notes):
        return text, []
    return ET.tostring(root, encoding="unicode"), notes


def _parse(text: str, where: str, name: str = "FILE"):
    """The parsed robot, the parser's complaints (unknown tags are not errors), what
    was read beyond URDF (``<frame>`` elements) and the text parsed (:func:`_rewritten`).
    A xacro file (macros, substitutions) and a file without links (a fragment that a
    xacro file includes) are refused with what to do.  The XML declaration is dropped
    first, wherever it stands: the text is already decoded, and a NAO file of ROS 2
    (ijnek/nao_description) has it after its licence comment, which ROS's parser reads
    and an XML parser refuses ("XML or text declaration not at start of entity")."""
    text = _XML_DECLARATION.sub("", text)
    marker = _xacro_marker(text)
    if marker is not None:
        raise ValueError(f"{where}: a xacro file, not a URDF ({marker[:80]}): "
                         f"{xacro_refusal(name)}")
    text, framed = _rewritten(text)
    said = []
    keep = _xml_core.on_error
    _xml_core.on_error = said.append
    try:
        robot = _urdf.URDF.from_xml_string(text.encode())
    except Exception as e:       # noqa: BLE001 - lxml, assertions and KeyErrors of the parser
        raise ValueError(f"{where}: cannot parse the URDF ({' '.join(str(e).split()) or type(e).__name__})"
                         ) from None
    finally:
        _xml_core.on_error = keep
    if not robot.links:
        raise ValueError(f"{where}: defines no <link>: not a robot's description (a fragment "
                         f"that a xacro file includes, e.g. ros2_control or gazebo tags?); "
                         f"import the robot's own file, expanded by xacro if it is one")
    return robot, _grouped(said), framed, text


def _grouped(said: list) -> list:
    """The parser's complaints, one line per kind: 'Unknown tag "contact" in /robot/...'
    said for every link becomes one line that counts the places and names the first."""
    places: dict = {}
    for line in said:
        head, sep, where = line.partition(" in /")
        places.setdefault(head if sep else line, []).append("/" + where if sep else "")
    return [head + ("" if not ws[0] else f" in {ws[0]}" if len(ws) == 1 else
                    f" in {len(ws)} places ({ws[0]}, ...)")
            for head, ws in places.items()]
