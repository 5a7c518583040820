"""What a batch enhances: mesh files, folders of them, or a manifest listing scans and their photos.

Manifests (paths relative to the manifest's folder):

- ``.json``: ``[{"mesh": "a.obj", "photos": "a_capture/", "ground_truth": "a_truth.obj", "name": "room_a"}, ...]``
  (or ``{"scans": [...]}``; an entry may be a plain mesh path);
- ``.csv``: a header row naming the same columns (``mesh`` required), one scan per row;
- ``.txt``: one scan per line: the mesh path, optionally followed by its photos path (quotes around a path
  with spaces); ``#`` starts a comment.

In a folder, every mesh file below it is a scan, except one named ``ground_truth.*``, which is taken as the
ground truth of the scans beside it (the layout ``scantex demo-scan`` writes).
"""

from __future__ import annotations

import csv
import json
import os
from dataclasses import dataclass
from pathlib import Path

from scantex.errors import ScanError
from scantex.io import READ_FORMATS

MANIFEST_FORMATS = (".json", ".csv", ".txt")


@dataclass(frozen=True)
class ScanInput:
    """One scan of a batch."""

    mesh: Path
    """the scan's mesh file"""
    photos: Path | None = None
    """its posed photos (enhance --photos), if any"""
    ground_truth: Path | None = None
    """its true texture on the same geometry (synthetic scans), if any"""
    name: str = ""
    """its output folder's name inside the batch folder (default: derived from the path)"""

    def to_dict(self) -> dict:
        return {"mesh": str(self.mesh), "photos": str(self.photos) if self.photos else None,
                "ground_truth": str(self.ground_truth) if self.ground_truth else None, "name": self.name}


def collect_inputs(inputs, exclude: Path | None = None) -> list[ScanInput]:
    """The scans named by ``inputs`` (mesh files, folders, manifests), each with a unique ``name``.

    Raises :class:`ScanError` for an input that does not exist, a folder holding no mesh, or a manifest
    that cannot be read. Files under ``exclude`` (the batch's own output folder) are never inputs.
    """
    scans: list[ScanInput] = []
    for raw in inputs:
        path = Path(raw)
        if not path.exists():
            raise ScanError(path, "no such file or folder")
        if path.is_dir():
            found = _scan_folder(path, exclude)
            if not found:
                raise ScanError(path, f"no mesh files ({', '.join(READ_FORMATS)}) in this folder")
            scans += found
        elif path.suffix.lower() in MANIFEST_FORMATS:
            scans += read_manifest(path)
        else:
            scans.append(ScanInput(path))
    if not scans:
        raise ScanError(None, "no scans to enhance")
    return _named(scans)


def read_manifest(path: Path) -> list[ScanInput]:
    """The scans a manifest file lists (formats in the module docstring)."""
    base = path.parent
    suffix = path.suffix.lower()
    try:
        text = path.read_text(encoding="utf-8-sig")  # a spreadsheet's CSV starts with a byte-order mark
    except (OSError, UnicodeDecodeError) as e:
        raise ScanError(path, f"cannot read the manifest ({e})") from None
    rows: list[dict] = []
    if suffix == ".json":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as e:
            raise ScanError(path, f"not a JSON manifest ({e})") from None
        entries = data.get("scans") if isinstance(data, dict) else data
        if not isinstance(entries, list):
            raise ScanError(path, "a JSON manifest is a list of scans, or {\"scans\": [...]}")
        for i, e in enumerate(entries):
            rows.append({"mesh": e} if isinstance(e, str) else e if isinstance(e, dict) else {"_bad": i})
    elif suffix == ".csv":
        reader = csv.DictReader(text.splitlines())
        if not reader.fieldnames or "mesh" not in [f.strip() for f in reader.fieldnames]:
            raise ScanError(path, "a CSV manifest needs a header row with a 'mesh' column")
        rows = [{k.strip(): (v or "").strip() for k, v in r.items() if k} for r in reader]
    else:
        for line in text.splitlines():
            line = line.split("#", 1)[0].strip()
            if line:
                parts = _txt_fields(line, base)
                rows.append({"mesh": parts[0], "photos": parts[1] if len(parts) > 1 else None})
    scans = []
    for i, row in enumerate(rows, 1):
        unknown = set(row) - {"mesh", "photos", "ground_truth", "name"}
        if "_bad" in row or not row.get("mesh") or unknown:
            what = f"unknown key '{sorted(unknown)[0]}'" if unknown else "no mesh path"
            raise ScanError(path, f"scan {i} of the manifest: {what}")
        scans.append(ScanInput(mesh=base / row["mesh"],
                               photos=base / row["photos"] if row.get("photos") else None,
                               ground_truth=base / row["ground_truth"] if row.get("ground_truth") else None,
                               name=str(row.get("name") or "")))
    return scans


def _txt_fields(line: str, base: Path) -> list[str]:
    """A ``.txt`` manifest line's mesh path and photos path: the whole line where it names a file (a path with
    spaces), else its fields as a shell splits them (quotes keep spaces: ``"My Scan/scan.obj" photos``)."""
    import shlex

    if (base / line).is_file():
        return [line]
    if '"' in line or "'" in line:
        try:
            return shlex.split(line)
        except ValueError:  # an unbalanced quote: plain fields
            pass
    return line.split()


def _scan_folder(folder: Path, exclude: Path | None) -> list[ScanInput]:
    exclude = exclude.resolve() if exclude is not None else None
    found = []
    for root, dirs, files in os.walk(folder):
        here = Path(root)
        dirs[:] = sorted(d for d in dirs if not d.startswith(".") and not d.endswith(".partial")
                         and (exclude is None or (here / d).resolve() != exclude))
        meshes = sorted(f for f in files if Path(f).suffix.lower() in READ_FORMATS and not f.startswith("."))
        truth = [f for f in meshes if Path(f).stem == "ground_truth"]
        for f in meshes:
            if Path(f).stem != "ground_truth":
                found.append(ScanInput(here / f, ground_truth=here / truth[0] if truth else None))
    return found


def _named(scans: list[ScanInput]) -> list[ScanInput]:
    """Give every scan a unique, stable output name: its file stem, or, where stems repeat, its path
    below the inputs' common folder (``room1/scan.obj`` -> ``room1__scan``)."""
    stems = [s.mesh.stem for s in scans if not s.name]
    unique = len(stems) == len(set(stems))
    unnamed = [s.mesh.resolve() for s in scans if not s.name]
    common = Path(os.path.commonpath([p.parent for p in unnamed])) if unnamed else None
    out, used = [], set()
    for s in scans:
        name = s.name
        if not name:
            if unique:
                name = s.mesh.stem
            else:
                rel = s.mesh.resolve().relative_to(common).with_suffix("")
                name = "__".join(rel.parts)
        name = "".join(c if c.isalnum() or c in "-_." else "_" for c in name).lstrip(".") or "scan"
        base, k = name, 2
        while name in used:
            name, k = f"{base}_{k}", k + 1
        used.add(name)
        out.append(ScanInput(s.mesh, s.photos, s.ground_truth, name))
    return out
