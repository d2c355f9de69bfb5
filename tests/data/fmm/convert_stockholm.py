"""Convert FMM's Stockholm shapefiles (``example/osmnx_example/stockholm``) to osmnx GraphML.

Run once by hand; the output, ``stockholm.graphml``, is what the tests import. Edges keep
FMM's ``fid`` column, the edge ids of FMM's matched output ``mr.txt``.

    python tests/data/fmm/convert_stockholm.py ../shared/peers/fmm/stockholm-osmnx \
        tests/data/fmm/stockholm.graphml
"""

import ast
import sys

import geopandas as gpd
import osmnx as ox


def main(src: str, out: str) -> None:
    edges = gpd.read_file(f"{src}/edges.shp").set_index(["u", "v", "key"])
    edges["oneway"] = edges["oneway"].astype(bool)
    edges["osmid"] = [ast.literal_eval(s) for s in edges["osmid"]]
    nodes = gpd.read_file(f"{src}/nodes.shp").set_index("osmid")
    nodes["x"] = nodes.geometry.x
    nodes["y"] = nodes.geometry.y
    graph = ox.graph_from_gdfs(nodes, edges, graph_attrs={"crs": "epsg:4326", "simplified": True})
    ox.save_graphml(graph, out)
    print(f"{out}: {graph.number_of_nodes()} nodes, {graph.number_of_edges()} edges")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
