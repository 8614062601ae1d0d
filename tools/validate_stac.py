#!/usr/bin/env python3
"""Validate a STAC item against the core Item schema and every extension it
declares, offline, with the schemas shipped in fixtures/stac_schemas/ (each
registered under the URL STAC gives it). Prints one line per problem and
exits 1 if there is any; used by tests/export_formats.rs through the
project's .venv (tools/setup.sh installs jsonschema there)."""
import json
import pathlib
import sys

import jsonschema
from referencing import Registry, Resource
from referencing.jsonschema import DRAFT7

CORE = "https://schemas.stacspec.org/v1.1.0/item-spec/json-schema/"
FILES = {
    CORE + "item.json": "item.json",
    CORE + "common.json": "common.json",
    CORE + "bands.json": "bands.json",
    CORE + "basics.json": "basics.json",
    CORE + "datetime.json": "datetime.json",
    CORE + "instrument.json": "instrument.json",
    CORE + "licensing.json": "licensing.json",
    CORE + "provider.json": "provider.json",
    CORE + "data-values.json": "data-values.json",
    "https://geojson.org/schema/Feature.json": "geojson-Feature.json",
    "https://geojson.org/schema/Geometry.json": "geojson-Geometry.json",
    "https://stac-extensions.github.io/raster/v1.1.0/schema.json": "raster-v1.1.0.json",
    "https://stac-extensions.github.io/projection/v1.1.0/schema.json": "projection-v1.1.0.json",
    "https://stac-extensions.github.io/processing/v1.2.0/schema.json": "processing-v1.2.0.json",
}


def main():
    item_path, schema_dir = pathlib.Path(sys.argv[1]), pathlib.Path(sys.argv[2])
    item = json.loads(item_path.read_text())
    resources = []
    for url, name in FILES.items():
        contents = json.loads((schema_dir / name).read_text())
        # Registered under the URL that refers to it (one upstream $id has
        # a typo); its own $id, if it differs, is dropped.
        contents.pop("$id", None)
        resources.append((url, Resource.from_contents(contents, default_specification=DRAFT7)))
    registry = Registry().with_resources(resources)
    schemas = [CORE + "item.json"] + list(item.get("stac_extensions", []))
    problems = 0
    for url in schemas:
        if url not in FILES:
            print(f"{item_path}: extension {url} has no schema in {schema_dir}")
            problems += 1
            continue
        validator = jsonschema.Draft7Validator(
            {"$ref": url}, registry=registry, format_checker=jsonschema.FormatChecker()
        )
        for err in validator.iter_errors(item):
            where = "/".join(str(p) for p in err.absolute_path)
            print(f"{item_path}: {url}: at '{where}': {err.message[:300]}")
            problems += 1
    if problems == 0:
        print(f"{item_path}: valid against {len(schemas)} schema(s)")
    sys.exit(1 if problems else 0)


if __name__ == "__main__":
    main()
