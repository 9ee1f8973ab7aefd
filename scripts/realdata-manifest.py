#!/usr/bin/env python3
# Maintainer tool for scripts/data-sources/manifest.txt, the list that scripts/fetch-realdata.py fetches.
#
#   realdata-manifest.py [--data DIR]                  hash DIR (default ../shared/realdata) and write the manifest:
#                                                      every file with its size, SHA-256 and upstream URL (FOLDERS)
#   realdata-manifest.py --check [--data DIR]          fail unless the manifest is what DIR gives
#   realdata-manifest.py --mirror OUT [--data DIR]     lay out DIR's files as the upstream servers serve them
#                                                      (OUT/<owner>/<repo>/<commit>/<path>), for testing the fetcher
#                                                      against a local HTTP server (POINTREGGPT_DATA_MIRROR)
#
# Where each folder comes from is its SOURCE.txt; FOLDERS below turns that into one rule per file.
import argparse
import importlib.util
import os
import shutil
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
spec = importlib.util.spec_from_file_location("fetch_realdata", os.path.join(ROOT, "scripts", "fetch-realdata.py"))
fetch = importlib.util.module_from_spec(spec)
spec.loader.exec_module(fetch)

RAW = "https://raw.githubusercontent.com/"

# source name -> (owner/repo, full commit, note). None of these paths is stored with Git LFS upstream (the
# repositories' .gitattributes track no PNG or text file there), so the raw URLs serve the files themselves.
SOURCES = {
    "tsdf-fusion-python": ("andyzeng/tsdf-fusion-python", "3f22a940d90f684145b1f29b1feaa92e09eb1db6", "SOURCE.txt's commit"),
    "tsdf-fusion": ("andyzeng/tsdf-fusion", "afbd0d16dcb2afb95e71d19fcddb2f926055d08b", "SOURCE.txt's commit"),
    "nvblox": ("nvidia-isaac/nvblox", "7c76f90749aa26b89faeca2044fbdcabd910d0a6", "SOURCE.txt's commit"),
    "semantic-instance-fusion": (
        "renezurbruegg/SemanticInstanceFusion", "f6521543c89a99d8fc28c63e61f77df0559ce95a",
        "SOURCE.txt names the snapshot c10f92eb, whose full hash was not found; this commit holds the same "
        "Dataset/ files (the one version of them seen; text files compared equal)"),
    "cuboid-slam": ("benchun123/cuboid_slam_with_bbox_constraints", "d228cfa2cd2bae42d568ee573165999977cc5e61",
                    "full hash of SOURCE.txt's d228cfa2"),
}


def tum_rule(data):
    """The TUM key frames: depth/<timestamp>.png is data/depth_imgs/<i>_depth_raw.png, i its row in the poses."""
    with open(os.path.join(data, "tum-fr3-cabinet-keyframes", "groundtruth.txt")) as f:
        stamps = [r[0] for r in fetch.rows_of_numbers(f.read(), 8, "groundtruth.txt")]
    index = {f"depth/{t}.png": i for i, t in enumerate(stamps)}
    poses = "cuboid-slam:data/truth_cam_poses.txt"

    def rule(rel):
        if rel in index:
            return ["fetch", f"cuboid-slam:data/depth_imgs/{index[rel]:04d}_depth_raw.png"]
        return {
            "TUM3.original.yaml": ["fetch", "cuboid-slam:data/TUM3.yaml"],
            "groundtruth.txt": ["derive", "tum-groundtruth", poses],
            "depth.txt": ["derive", "tum-depth-list", poses],
        }.get(rel)

    return rule


def prefix_rule(source, prefix):
    return lambda rel: ["fetch", f"{source}:{prefix}{rel}"]


def icl_rule(rel):
    if rel == "camera-intrinsics.original.txt":
        return ["fetch", "semantic-instance-fusion:Dataset/camera-intrinsics.txt"]
    if rel == "intrinsic/intrinsic_depth.txt":
        return ["derive", "intrinsic-4x4", "icl-nuim-livingroom/camera-intrinsics.original.txt"]
    if rel.startswith(("depth/", "pose/")):
        return ["fetch", f"semantic-instance-fusion:Dataset/{rel}"]
    return None


# folder -> function(data dir) -> rule(path inside the folder) -> manifest words after the pins.
# depth_stats.tsv (the team's per-frame summary) is made from the folder's PNGs; SOURCE.txt (the team's
# provenance note) is kept in the checkout as scripts/data-sources/<folder>.SOURCE.txt and copied.
FOLDERS = {
    "7scenes-redkitchen": lambda data: prefix_rule("tsdf-fusion-python", "data/"),
    "apcbox-realsense": lambda data: prefix_rule("tsdf-fusion", "old-version/data/sample/"),
    "sun3d-studyroom-5frames": lambda data: prefix_rule("nvblox", "nvblox/tests/data/3dmatch/"),
    "icl-nuim-livingroom": lambda data: icl_rule,
    "tum-fr3-cabinet-keyframes": tum_rule,
}


def how(folder, rel, rule):
    name = os.path.basename(rel)
    if rel == "SOURCE.txt":
        return ["copy", f"scripts/data-sources/{folder}.SOURCE.txt"]
    if name == "depth_stats.tsv":
        return ["derive", "depth-stats", "pattern=*.depth.png"]
    words = rule(rel)
    if words is None:
        raise SystemExit(f"realdata-manifest: no rule for {folder}/{rel}: add one to FOLDERS")
    return words


def manifest_text(data):
    lines = [
        "# The real depth frames the tests read: scripts/fetch-realdata.py fetches them into a cache folder.",
        "# Written by scripts/realdata-manifest.py from ../shared/realdata; do not edit by hand.",
        "#   source <name> <URL prefix>                   a public repository at a pinned commit",
        "#   file <path> <size> <sha256> fetch <name>:<path>  downloaded from that source",
        "#   file <path> <size> <sha256> derive <how> <input>...  made from fetched originals (fetch-realdata.py's",
        "#        DERIVATIONS; an input <name>:<path> is an upstream file, pinned only through the result)",
        "#   file <path> <size> <sha256> copy <checkout path>   the team's own note, kept in the checkout",
        "# The TUM pose list (cuboid-slam:data/truth_cam_poses.txt) is not kept here and was not seen from this",
        "# project's machines: groundtruth.txt and depth.txt copy its numbers as written, and their pins check it.",
    ]
    for name, (repo, commit, note) in SOURCES.items():
        lines.append(f"# {name}: {repo} at {commit} ({note})")
        lines.append(f"source {name} {RAW}{repo}/{commit}/")
    for folder, make_rule in FOLDERS.items():
        rule = make_rule(data)
        base = os.path.join(data, folder)
        for dirpath, _, files in sorted(os.walk(base)):
            for name in sorted(files):
                path = os.path.join(dirpath, name)
                rel = os.path.relpath(path, base).replace(os.sep, "/")
                words = how(folder, rel, rule)
                lines.append(" ".join(["file", f"{folder}/{rel}", str(os.path.getsize(path)), fetch.file_sha256(path)] + words))
    return "\n".join(lines) + "\n"


def write_mirror(data, out):
    """Copies DIR's fetched files to OUT as the servers lay them out, and writes the TUM pose list back from
    groundtruth.txt (the one upstream input the data folder does not hold as it is)."""
    sources, entries = fetch.read_manifest(fetch.MANIFEST)
    for e in entries:
        if e.how == "fetch":
            dst = os.path.join(out, fetch.source_url(sources, e.args[0]).split("/", 3)[3])
            os.makedirs(os.path.dirname(dst), exist_ok=True)
            shutil.copyfile(os.path.join(data, e.path), dst)
    for e in entries:
        for a in e.args[1:] if e.how == "derive" else []:
            if a == "cuboid-slam:data/truth_cam_poses.txt":
                with open(os.path.join(data, "tum-fr3-cabinet-keyframes", "groundtruth.txt")) as f:
                    rows = fetch.rows_of_numbers(f.read(), 8, "groundtruth.txt")
                dst = os.path.join(out, fetch.source_url(sources, a).split("/", 3)[3])
                os.makedirs(os.path.dirname(dst), exist_ok=True)
                with open(dst, "w") as f:
                    f.write("".join(" ".join(r) + "\n" for r in rows))


def main():
    ap = argparse.ArgumentParser(description="Writes, checks or mirrors scripts/data-sources/manifest.txt.")
    ap.add_argument("--data", default=os.path.join(ROOT, "..", "shared", "realdata"))
    ap.add_argument("--check", action="store_true", help="fail unless the manifest matches --data")
    ap.add_argument("--mirror", metavar="OUT", help="write a local copy laid out as the upstream servers serve it")
    a = ap.parse_args()
    data = os.path.abspath(a.data)
    if a.mirror:
        write_mirror(data, a.mirror)
        return 0
    text = manifest_text(data)
    if a.check:
        with open(fetch.MANIFEST) as f:
            if f.read() != text:
                print(f"realdata-manifest: {fetch.MANIFEST} is not what {data} gives: rerun scripts/realdata-manifest.py", file=sys.stderr)
                return 1
        return 0
    with open(fetch.MANIFEST, "w") as f:
        f.write(text)
    for folder in FOLDERS:
        shutil.copyfile(os.path.join(data, folder, "SOURCE.txt"), os.path.join(ROOT, "scripts", "data-sources", f"{folder}.SOURCE.txt"))
    print(f"realdata-manifest: wrote {fetch.MANIFEST} ({text.count(chr(10) + 'file ')} files)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
