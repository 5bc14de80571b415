"""OpenStreetMap sources -> lines, stops and switch counts.

Two readers fill one in-memory model (:class:`OsmData`), and one converter (:func:`osm_to_batch`) turns
it into an :class:`ImportBatch`:

- ``.osm.pbf`` / ``.osm`` (XML, also ``.osm.gz``/``.osm.bz2``) with pyosmium (``pip install
  'sfa-positioning[osm]'``), imported only when such a file is read;
- OSM GeoJSON exports (overpass-turbo / osmtogeojson: features ``way/N``, ``node/N``, ``relation/N``,
  membership in each member's ``@relations``; route relations with a (Multi)LineString or a null
  geometry), with the standard library only (see :func:`from_geojson_features`).

Conversion (docs/track-db.md, "OpenStreetMap"):

1. Route relations (``type=route``, ``route`` one of the routes of the selected ``railway`` values, and
   matching every ``--tag``) become one line each: their member ways (platform roles excluded), in
   member order, stitched by :func:`track_db.stitch.stitch_parts`; the relation's ``name`` (else
   ``ref``) names the line; its stops are the relation's stop members (else its platform members),
   each node once.
2. Ways of the selected ``railway`` values (matching every ``--tag``) that are in no imported relation
   are joined through nodes where exactly two of them end and no other track passes (degree-2 nodes)
   into one line per chain.
3. Switches: ``railway=switch`` nodes on the imported track and shared nodes where three or more track
   ends meet are counted; the database's junctions come from the shared vertices (track_db.topology).
4. Nodes are identified by their position (OSM stores 1e-7 degree): exact for .pbf/.osm, and the only
   identity a GeoJSON export keeps.

Everything that is not taken is counted in the batch's notes, never an error: features without
geometry, non-line features, relations of other kinds, member ways missing from a cropped extract.
"""

from __future__ import annotations

import re
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..build import LineGeometry, StopPoint
from ..errors import ImportFailed
from ..stitch import stitch_parts
from . import ImportBatch, ImportOptions

__all__ = [
    "OSM_ATTRIBUTION",
    "RAILWAY_TRACKS",
    "OsmData",
    "from_geojson_features",
    "is_osm_geojson",
    "osm_to_batch",
    "read_osm_file",
]

#: attribution every OpenStreetMap-derived database must carry (ODbL 1.0, section 4.3)
OSM_ATTRIBUTION = "(c) OpenStreetMap contributors, ODbL 1.0 (https://www.openstreetmap.org/copyright)"
#: ``railway=*`` values that are track (default selection of --railway)
RAILWAY_TRACKS = ("rail", "tram", "subway", "light_rail", "narrow_gauge", "monorail", "funicular")
#: the ``route=*`` values of the relations that run on each railway value
ROUTES_OF = {
    "rail": ("train", "railway"),
    "narrow_gauge": ("train", "railway"),
    "tram": ("tram",),
    "subway": ("subway",),
    "light_rail": ("light_rail",),
    "monorail": ("monorail",),
    "funicular": ("funicular",),
}
STOP_ROLES = ("stop", "stop_entry_only", "stop_exit_only")
PLATFORM_ROLES = ("platform", "platform_entry_only", "platform_exit_only")
#: nodes that are stops when no route relation gives them
STOP_TAGS = {"railway": ("tram_stop", "stop", "halt", "station"), "public_transport": ("stop_position",)}
_SCALE = 1e7  # OSM coordinate precision: 1e-7 degree
_ID = re.compile(r"^(node|way|relation|rel|n|w|r)/(-?\d+)$")


@dataclass
class OsmWay:
    osm_id: int
    tags: dict[str, str]
    parts: list[np.ndarray]  #: runs of consecutive nodes present in the file, (k, 2) lon, lat


@dataclass
class OsmRelation:
    osm_id: int
    tags: dict[str, str]
    ways: list[tuple[int, str]] = field(default_factory=list)  #: (way id, role) in member order
    nodes: list[tuple[int, str]] = field(default_factory=list)  #: (node id, role) in member order
    geometry: list[np.ndarray] | None = None  #: (Multi)LineString of a GeoJSON export, if given


@dataclass
class OsmNode:
    osm_id: int
    tags: dict[str, str]
    lon: float
    lat: float


@dataclass
class OsmData:
    ways: dict[int, OsmWay] = field(default_factory=dict)
    relations: dict[int, OsmRelation] = field(default_factory=dict)
    nodes: dict[int, OsmNode] = field(default_factory=dict)  #: tagged nodes only
    skipped: Counter = field(default_factory=Counter)  #: what the reader did not take, by reason
    missing_nodes: int = 0  #: way nodes without a location (outside a cropped extract)


def feature_parts(k: int, feat) -> tuple[str, dict, object]:
    """Feature number k of a FeatureCollection: its label for errors, its properties and its geometry
    (None when null); a non-Feature or non-object properties is an ImportFailed naming it."""
    where = f"feature {k}"
    if not isinstance(feat, dict) or feat.get("type") != "Feature":
        raise ImportFailed(f"{where}: not a GeoJSON Feature")
    props = feat.get("properties") or {}
    if not isinstance(props, dict):
        raise ImportFailed(f"{where}: properties must be an object, got {props!r}")
    return where, props, feat.get("geometry")

def _key(lon: float, lat: float) -> tuple[int, int]:
    return (round(lon * _SCALE), round(lat * _SCALE))


# ---------------------------------------------------------------------------------------------- readers


def read_osm_file(src: Path) -> OsmData:
    """Read an .osm.pbf / .osm file with pyosmium (railway ways, tagged nodes, route relations)."""
    try:
        import osmium
    except ImportError:
        raise ImportFailed(
            f"{src}: reading .osm.pbf / .osm files needs pyosmium: pip install 'sfa-positioning[osm]' "
            "(or export the area as GeoJSON, which needs no extra)"
        ) from None
    data = OsmData()
    try:
        # node locations are cached before the filter, so ways keep their untagged nodes' positions;
        # the filter only spares Python the objects that cannot matter (untagged nodes, other ways)
        processor = (
            osmium.FileProcessor(str(src))
            .with_locations()
            .with_filter(osmium.filter.KeyFilter("railway", "public_transport", "route"))
        )
        for obj in processor:
            if obj.is_node():
                tags = dict(obj.tags)
                if tags and ("railway" in tags or "public_transport" in tags):
                    loc = obj.location
                    if loc.valid():
                        data.nodes[obj.id] = OsmNode(obj.id, tags, loc.lon, loc.lat)
            elif obj.is_way():
                if "railway" not in obj.tags:
                    continue
                parts, run = [], []
                for nd in obj.nodes:
                    if nd.location.valid():
                        run.append((nd.lon, nd.lat))
                    else:
                        data.missing_nodes += 1
                        parts.append(run)
                        run = []
                parts.append(run)
                arrays = [np.array(r, dtype=np.float64) for r in parts if len(r) >= 2]
                data.ways[obj.id] = OsmWay(obj.id, dict(obj.tags), arrays)
            elif obj.is_relation():
                tags = dict(obj.tags)
                if tags.get("type") != "route":
                    data.skipped["relations that are not routes"] += 1
                    continue
                rel = OsmRelation(obj.id, tags)
                for m in obj.members:
                    if m.type == "w":
                        rel.ways.append((m.ref, m.role))
                    elif m.type == "n":
                        rel.nodes.append((m.ref, m.role))
                data.relations[obj.id] = rel
    except RuntimeError as exc:  # pyosmium reports unreadable and malformed files as RuntimeError
        raise ImportFailed(f"{src}: cannot read as OSM data: {exc}") from None
    return data


def _osm_id(feat: dict, props: dict) -> tuple[str, int] | None:
    for raw in (feat.get("id"), props.get("@id"), props.get("id")):
        m = _ID.match(str(raw)) if raw is not None else None
        if m:
            kind = {"n": "node", "w": "way", "r": "relation", "rel": "relation"}.get(m.group(1), m.group(1))
            return kind, int(m.group(2))
    return None


def is_osm_geojson(feats: list) -> bool:
    """An OSM export with ways or memberships (a file of route relations and points alone is not)."""
    for feat in feats:
        if not isinstance(feat, dict):
            continue
        props = feat.get("properties") or {}
        if not isinstance(props, dict):
            continue  # reported by the reader that reads it
        if "@relations" in props:
            return True
        ident = _osm_id(feat, props)
        if ident and ident[0] == "way":
            return True
    return False


def _tags(props: dict) -> dict[str, str]:
    return {str(k): str(v) for k, v in props.items() if not str(k).startswith("@") and k != "id"}


def _lines_of(geom: dict, where: str, positions) -> list[np.ndarray] | None:
    gtype = geom.get("type")
    coords = geom.get("coordinates")
    if gtype == "LineString":
        raw = [coords]
    elif gtype == "MultiLineString" and isinstance(coords, list):
        raw = coords
    else:
        return None
    out = []
    for j, part in enumerate(raw):
        if isinstance(part, list) and len(part) >= 2:
            out.append(positions(part, f"{where} part {j}")[:, :2])
    return out


def from_geojson_features(feats: list, positions) -> OsmData:
    """The OSM model of a GeoJSON export's features (``positions`` validates a coordinate list)."""
    data = OsmData()

    def relation(rel_id: int, reltags: dict | None) -> OsmRelation:
        rel = data.relations.get(rel_id)
        if rel is None:
            rel = data.relations[rel_id] = OsmRelation(rel_id, {})
        if reltags and not rel.tags:
            rel.tags = _tags(reltags)
        return rel

    for k, feat in enumerate(feats):
        where, props, geom = feature_parts(k, feat)
        ident = _osm_id(feat, props)
        if ident is None:
            data.skipped["features without an OSM id"] += 1
            continue
        kind, osm_id = ident
        if kind == "relation":
            rel = relation(osm_id, None)
            rel.tags = _tags(props)
            if geom is not None:
                rel.geometry = _lines_of(geom, where, positions) if isinstance(geom, dict) else None
            if rel.tags.get("type") != "route":
                data.skipped["relations that are not routes"] += 1
                del data.relations[osm_id]
            continue
        if geom is None:
            data.skipped["features with null geometry"] += 1
            continue
        if not isinstance(geom, dict):
            raise ImportFailed(f"{where}: geometry is not a GeoJSON object")
        for m in props.get("@relations") or []:
            rel_id = m.get("rel") if isinstance(m, dict) else None
            if not (isinstance(rel_id, int) or (isinstance(rel_id, str) and rel_id.isdigit())):
                raise ImportFailed(f"{where}: @relations entry without a relation id: {m!r}")
            rel = relation(int(rel_id), m.get("reltags") if isinstance(m.get("reltags"), dict) else None)
            (rel.ways if kind == "way" else rel.nodes).append((osm_id, str(m.get("role") or "")))
        tags = _tags(props)
        if kind == "node" and geom.get("type") == "Point":
            pos = positions([geom.get("coordinates")], where)[0]
            data.nodes[osm_id] = OsmNode(osm_id, tags, float(pos[0]), float(pos[1]))
        elif kind == "way" and "railway" in tags:
            lines = _lines_of(geom, where, positions)
            if lines is None:
                data.skipped[f"{geom.get('type')} ways"] += 1
            else:
                data.ways[osm_id] = OsmWay(osm_id, tags, lines)
        else:
            data.skipped[f"{kind} features that are not railway lines or points"] += 1
    for rel_id in [r for r, rel in data.relations.items() if rel.tags.get("type") != "route"]:
        del data.relations[rel_id]  # known from a member's @relations only, and not a route
    return data


# -------------------------------------------------------------------------------------------- converter


def _matches(tags: dict[str, str], filters: tuple[tuple[str, str | None], ...]) -> bool:
    return all(k in tags and (v is None or tags[k] == v) for k, v in filters)


def _line_name(tags: dict[str, str], fallback: str) -> str:
    if tags.get("name"):
        return tags["name"]
    ref = tags.get("ref")
    if ref and tags.get("from") and tags.get("to"):
        return f"{ref}: {tags['from']} -> {tags['to']}"
    return ref or fallback


def _route_matches(rel: OsmRelation, route: str) -> bool:
    keys = (rel.tags.get("ref"), rel.tags.get("name"), f"relation/{rel.osm_id}", str(rel.osm_id))
    return any(k is not None and k == route for k in keys)


def _stops_of(rel: OsmRelation, data: OsmData) -> tuple[list[OsmNode], int]:
    """The relation's stop nodes (else its platform nodes), each once; and how many had no name."""
    for roles in (STOP_ROLES, PLATFORM_ROLES):
        members = [data.nodes.get(n) for n, role in rel.nodes if role in roles]
        found = [m for m in members if m is not None]
        if found:
            named = [m for m in found if m.tags.get("name")]
            return named, len(found) - len(named)
    return [], 0


def _chains(ways: list[OsmWay], degree: Counter) -> list[tuple[list[int], np.ndarray]]:
    """Join way parts end to end through nodes of degree 2: (way ids, (k, 2) lon, lat) per chain."""
    edges = [(w.osm_id, p) for w in ways for p in w.parts]
    ends: dict[tuple[int, int], list[tuple[int, int]]] = {}
    for e, (_, p) in enumerate(edges):
        ends.setdefault(_key(*p[0]), []).append((e, 0))
        ends.setdefault(_key(*p[-1]), []).append((e, -1))

    def through(key) -> tuple[int, int] | None:
        at = ends.get(key, [])
        return at if degree[key] == 2 and len(at) == 2 else None

    used = [False] * len(edges)
    chains = []
    order = sorted(range(len(edges)), key=lambda e: (edges[e][0], e))
    # open chains first (start where the chain cannot be continued backwards), then closed loops
    starts = [e for e in order if through(_key(*edges[e][1][0])) is None] + order
    for first in starts:
        if used[first]:
            continue
        used[first] = True
        ids = [edges[first][0]]
        coords = [edges[first][1]]
        key = _key(*coords[-1][-1])
        while (at := through(key)) is not None:
            nxt = [(e, side) for e, side in at if not used[e]]
            if not nxt:
                break
            e, side = nxt[0]
            used[e] = True
            part = edges[e][1] if side == 0 else edges[e][1][::-1]
            coords.append(part[1:])
            ids.append(edges[e][0])
            key = _key(*part[-1])
        chains.append((ids, np.concatenate(coords)))
    return chains


def osm_to_batch(data: OsmData, src: Path, options: ImportOptions) -> ImportBatch:
    railways = tuple(options.railway) if options.railway else RAILWAY_TRACKS
    routes = {r for rw in railways for r in ROUTES_OF.get(rw, (rw,))}
    filters = tuple(options.tags)
    attribution = options.attribution or OSM_ATTRIBUTION
    notes: list[str] = []
    skipped = Counter(data.skipped)
    lines: list[LineGeometry] = []
    stops: dict[tuple[int | None, int, int], StopPoint] = {}  #: (line or None, node position)
    line_keys: set[tuple[int, int]] = set()

    def add_line(name, coords, refs, label, props):
        line_keys.update(_key(*c) for c in coords[:, :2])
        lines.append(
            LineGeometry(
                name=name,
                lat_deg=coords[:, 1],
                lon_deg=coords[:, 0],
                source=f"{src.name} {label}",
                attribution=attribution,
                properties=props,
                label=f"{src.name} {label}",
                vertex_refs=refs,
            )
        )

    # 1. route relations
    chosen = []
    for rel_id in sorted(data.relations):
        rel = data.relations[rel_id]
        if rel.tags.get("route") not in routes:
            skipped[f"route relations of other kinds (route={rel.tags.get('route')})"] += 1
        elif not _matches(rel.tags, filters):
            skipped["route relations not matching --tag"] += 1
        else:
            chosen.append(rel)
    if options.route is not None:
        picked = [r for r in chosen if _route_matches(r, options.route)]
        if not picked:
            known = sorted({r.tags.get("ref") or r.tags.get("name") or str(r.osm_id) for r in chosen})
            raise ImportFailed(f"{src}: unknown route {options.route!r} (relations have: {', '.join(known)})")
        chosen = picked
    in_relation: set[int] = set()
    missing_members = 0
    unnamed_stops = 0
    for rel in chosen:
        label = f"relation {rel.osm_id}"
        members = [w for w, role in rel.ways if role not in PLATFORM_ROLES]
        present = [w for w in members if w in data.ways and "railway" in data.ways[w].tags]
        missing_members += len(members) - len(present)
        parts = [p for w in present for p in data.ways[w].parts]
        if not parts and rel.geometry:
            parts = rel.geometry
        if not parts:
            skipped["route relations without any member way in the file"] += 1
            continue
        try:
            res = stitch_parts(
                parts,
                label=f"{label} ({_line_name(rel.tags, label)})",
                snap_m=options.snap_m,
                max_gap_m=options.max_gap_m,
            )
        except ImportFailed as exc:  # one relation that cannot be joined does not block the others
            notes.append(f"{exc}: relation not imported (its ways are imported as ways in no relation)")
            skipped["route relations whose ways do not join within --max-gap-m"] += 1
            continue
        in_relation.update(present)
        if res.parts_dropped or res.gaps_bridged_m:
            notes.append(
                f"{label} ({_line_name(rel.tags, label)}): {res.parts_used} parts stitched, "
                f"{res.parts_dropped} off the main path dropped ({res.dropped_length_m:.0f} m), "
                f"{len(res.gaps_bridged_m)} gaps bridged ({sum(res.gaps_bridged_m):.0f} m)"
            )
        props = dict(rel.tags)
        props["@id"] = f"relation/{rel.osm_id}"
        props["@ways"] = f"{len(present)} of {len(members)} member ways in the file"
        add_line(_line_name(rel.tags, label), res.coords, res.refs, label, props)
        found, unnamed = _stops_of(rel, data)
        unnamed_stops += unnamed
        line = len(lines) - 1
        for node in found:  # the relation's own stops, each node once per line
            point = StopPoint(node.tags["name"], node.lat, node.lon, line=line)
            stops.setdefault((line, *_key(node.lon, node.lat)), point)

    n_relations = len(lines)

    # 2. ways in no imported relation, joined through degree-2 nodes
    track = [w for w in data.ways.values() if w.tags.get("railway") in railways or w.osm_id in in_relation]
    loose = [
        w
        for w in sorted(track, key=lambda w: w.osm_id)
        if w.osm_id not in in_relation and w.tags.get("railway") in railways and w.parts
    ]
    filtered = [w for w in loose if _matches(w.tags, filters)]
    if len(filtered) < len(loose):
        skipped["ways not matching --tag"] += len(loose) - len(filtered)
    degree: Counter = Counter()
    for w in track:
        for p in w.parts:
            keys = [_key(*c) for c in p]
            degree[keys[0]] += 1
            degree[keys[-1]] += 1
            for k in keys[1:-1]:
                degree[k] += 2
    n_chains = 0
    if options.routes_only:
        skipped["ways in no route relation (--routes-only)"] += len(filtered)
    else:
        for ids, coords in _chains(filtered, degree):
            head = data.ways[ids[0]].tags
            names = {data.ways[i].tags.get("name") for i in ids}
            name = names.pop() if len(names) == 1 and None not in names else None
            extra = f" (+{len(ids) - 1} ways)" if len(ids) > 1 else ""
            name = name or f"{head.get('railway')} way {ids[0]}{extra}"
            props = dict(head)
            props["@id"] = f"way/{ids[0]}"
            props["@ways"] = ",".join(str(i) for i in ids)
            refs = [f"way chain {ids[0]} vertex {v}" for v in range(len(coords))]
            add_line(name, coords, refs, f"way {ids[0]}{extra}", props)
            n_chains += 1
    if not lines:
        sel = ",".join(railways)
        raise ImportFailed(
            f"{src}: no route relation or railway way selected (--railway {sel}"
            + (f", --tag {' '.join(f'{k}={v}' if v else k for k, v in filters)}" if filters else "")
            + ")"
            + _skipped_text(skipped)
        )

    # stops of files without (selected) route relations: named stop-tagged nodes, each once (the build
    # keeps those within its stop tolerance of a line)
    if not chosen:
        for node in sorted(data.nodes.values(), key=lambda n: n.osm_id):
            is_stop = any(node.tags.get(k) in v for k, v in STOP_TAGS.items())
            if is_stop and node.tags.get("name"):
                point = StopPoint(node.tags["name"], node.lat, node.lon)
                stops.setdefault((None, *_key(node.lon, node.lat)), point)

    # 3. switches
    switches = sum(
        1
        for n in data.nodes.values()
        if n.tags.get("railway") == "switch" and _key(n.lon, n.lat) in line_keys
    )
    shared = sum(1 for k, d in degree.items() if d >= 3 and k in line_keys)

    notes.insert(
        0,
        f"OSM: {n_relations} route "
        f"relations and {n_chains} chains of other ways imported (--railway {','.join(railways)}); "
        f"{len({k[1:] for k in stops})} stop nodes ({len(stops)} line stops); {switches} railway=switch "
        f"nodes and {shared} shared nodes where 3 or more track ends meet on the imported track",
    )
    if missing_members or data.missing_nodes:
        notes.append(
            f"cropped extract: {missing_members} member ways of the imported relations and "
            f"{data.missing_nodes} way nodes are not in the file (the lines cover what is there)"
        )
    if unnamed_stops:
        notes.append(f"{unnamed_stops} stop members without a name skipped")
    if skipped:
        notes.append("skipped" + _skipped_text(skipped).removeprefix(";"))
    return ImportBatch(lines, list(stops.values()), notes)


def _skipped_text(skipped: Counter) -> str:
    if not skipped:
        return ""
    return "; " + ", ".join(f"{n} {what}" for what, n in sorted(skipped.items()))
