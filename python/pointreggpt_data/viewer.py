"""A 3D look at one pair with Rerun (the optional ``viewer`` extra: ``pip install "./python[viewer]"``, the
``rerun-sdk`` wheel, which brings its own viewer; nothing of the pointreggpt crate).

    import pointreggpt_data as prd
    prd.show_pair("out/demo", "synthetic-0/frame-000003#0")     # a viewer window, or an .rrd file without a display
    prd.show_pair(ds, 17, save="pair.rrd")                       # by unit index, always to a file

The recording (entity paths, for scripts that read it back):

* ``world/source``: the source cloud, in the source camera frame (metres), blue;
* ``world/target/reprojected``, ``world/target/scene``, ``world/target/made_up``: the target cloud moved
  into the source frame (``p_s = R^T (p_t - t)`` with ``T_target_from_source``), split by each point's
  dominant provenance: re-projected from the source frame (``target_known_share``, green), seen by the
  scene of posed frames around it (``target_scene_share``, orange), made up by a fill (``1 - known -
  scene``, red). A version-1 dataset has no provenance: ``world/target`` (grey);
* ``images/source_depth``, ``images/condition_depth``, ``images/target_depth`` (depth images, metres) and
  ``images/known_mask`` when the dataset stored depth maps (``output.depth_maps``);
* ``pair``: the pair key, pose, overlaps and the point counts of each kind, as text.
"""

import io
import os
import sys

import numpy as np

#: The depth-image columns, in the order shown, with their entity names.
IMAGE_COLUMNS = (("source_depth_png", "source_depth"), ("condition_depth_png", "condition_depth"),
                 ("target_depth_png", "target_depth"), ("known_mask_png", "known_mask"))
#: The three kinds of target point and their colours (RGB).
KINDS = (("reprojected", (60, 200, 90)), ("scene", (245, 160, 40)), ("made_up", (220, 50, 50)))
SOURCE_COLOUR = (90, 130, 235)


def _rerun():
    try:
        import rerun as rr
        import rerun.blueprint as rrb
    except ImportError as e:  # the extra is optional
        raise ImportError(f"show_pair needs the viewer extra: pip install \"./python[viewer]\" (rerun-sdk): {e}") from None
    return rr, rrb


def has_display():
    """Whether a viewer window can open here: on Linux, an X11 or Wayland display; elsewhere assumed."""
    if sys.platform.startswith("linux"):
        return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    return True


def provenance_kinds(known, scene):
    """Each target point's dominant kind: 0 re-projected, 1 scene, 2 made up (``1 - known - scene``, in
    float64, clipped to 0..1); ties go to the earlier kind."""
    known = np.asarray(known, dtype=np.float64)
    scene = np.asarray(scene, dtype=np.float64) if scene is not None else np.zeros_like(known)
    made = np.clip(1.0 - known - scene, 0.0, 1.0)
    return np.argmax(np.stack([known, scene, made], axis=1), axis=1)


def target_in_source_frame(target, T):
    """``p_s = R^T (p_t - t)``: target-frame points in the source camera frame (float32)."""
    T = np.asarray(T, dtype=np.float64)
    R, t = T[:3, :3], T[:3, 3]
    return ((np.asarray(target, dtype=np.float64) - t) @ R).astype(np.float32)


def _decode_png(data):
    from PIL import Image  # a dependency of rerun-sdk

    with Image.open(io.BytesIO(bytes(data))) as im:
        return np.asarray(im)


def _find(dataset, key, storage_options):
    """The pair ``key`` (a pair key or a unit index) of ``dataset`` with its depth images, any status."""
    import pyarrow.compute as pc

    from .dataset import open_dataset

    ds = dataset if hasattr(dataset, "shards") else open_dataset(dataset, storage_options=storage_options)
    where = pc.field("unit_index") == int(key) if isinstance(key, (int, np.integer)) else pc.field("pair_key") == str(key)
    names = set(ds.shard_schema(ds.shards[0]).names) if ds.shards else set()
    columns = [c for c, _ in IMAGE_COLUMNS if c in names] + [c for c in ("source_intrinsics", "target_intrinsics") if c in names]
    for pair in ds.pairs(status=None, where=where, columns=columns):
        return pair
    raise KeyError(f"{ds.url}: no pair {key!r}")


def log_pair(pair, recording=None):
    """Logs ``pair`` (a pair dict; with its ``*_depth_png`` / ``known_mask_png`` columns when given) into
    ``recording`` (default: the current Rerun recording). Returns the point count of each target kind."""
    rr, _ = _rerun()
    log = recording.log if recording is not None else rr.log
    to_np = lambda v: v.numpy() if hasattr(v, "numpy") else np.asarray(v)
    src = to_np(pair["source_points"]).astype(np.float32)
    tgt = target_in_source_frame(to_np(pair["target_points"]), to_np(pair["T_target_from_source"]))
    log("world", rr.ViewCoordinates.RDF, static=True)  # camera frame: x right, y down, z forward
    log("world/source", rr.Points3D(src, colors=np.tile(np.array(SOURCE_COLOUR, np.uint8), (len(src), 1)), radii=0.004))
    counts = {}
    known = pair.get("target_known_share")
    if known is None:
        log("world/target", rr.Points3D(tgt, colors=np.tile(np.array((160, 160, 160), np.uint8), (len(tgt), 1)), radii=0.004))
        counts["target"] = int(len(tgt))
    else:
        scene = pair.get("target_scene_share")
        kinds = provenance_kinds(to_np(known), None if scene is None else to_np(scene))
        for k, (name, colour) in enumerate(KINDS):
            sel = tgt[kinds == k]
            log(f"world/target/{name}", rr.Points3D(sel, colors=np.tile(np.array(colour, np.uint8), (len(sel), 1)), radii=0.004))
            counts[name] = int(len(sel))
    for column, name in IMAGE_COLUMNS:
        data = pair.get(column)
        if not data:
            continue
        image = _decode_png(data)
        if column == "known_mask_png":
            log(f"images/{name}", rr.Image(image.astype(np.uint8)))
        else:
            log(f"images/{name}", rr.DepthImage(image.astype(np.uint16), meter=1000.0))
    T = to_np(pair["T_target_from_source"])
    text = "\n".join([
        f"pair {pair.get('pair_key', '')} (unit {pair.get('unit_index', '')}, {pair.get('status', '')})",
        f"source points {len(src)}, target points {len(tgt)}: " + ", ".join(f"{k} {v}" for k, v in counts.items()),
        f"overlap source {pair.get('overlap_source', float('nan')):.3f}, target {pair.get('overlap_target', float('nan')):.3f}",
        "T_target_from_source =", np.array2string(T, precision=4, suppress_small=True),
    ])
    log("pair", rr.TextDocument(text))
    return counts


def _blueprint(rrb, images):
    views = [rrb.Spatial2DView(origin=f"images/{name}", name=name) for name in images]
    space = rrb.Spatial3DView(origin="world", name="pair (source frame)")
    right = rrb.Vertical(rrb.Grid(*views), rrb.TextDocumentView(origin="pair", name="pair"), row_shares=[4, 1]) if views \
        else rrb.TextDocumentView(origin="pair", name="pair")
    return rrb.Blueprint(rrb.Horizontal(space, right, column_shares=[3, 2]), collapse_panels=True)


def show_pair(source, key=None, save=None, spawn=None, storage_options=None):
    """Shows one pair in Rerun: both clouds in the source camera frame, the target's points coloured by
    provenance (re-projected, scene, made up), the depth images beside them.

    ``source``: a pair dict (``Dataset.pairs(columns=[...png columns])``, ``PairDataset``), or a dataset
    (a ``Dataset``, a folder or URL) with ``key`` (a pair key or a unit index; any status). ``save``: write
    the recording to this ``.rrd`` file instead of showing it. ``spawn``: ``True`` opens the viewer,
    ``False`` writes a file; default: the viewer when there is a display (``has_display``), else
    ``pair-<unit>.rrd`` in the working folder. Returns the path of the ``.rrd`` written, or ``None`` when
    shown in the viewer; the file opens with ``rerun <file>``.
    """
    rr, rrb = _rerun()
    pair = source if isinstance(source, dict) else _find(source, key, storage_options)
    if save is None and spawn is None:
        spawn = has_display()
    if save is None and not spawn:
        save = f"pair-{pair.get('unit_index', 'x')}.rrd"
    rec = rr.RecordingStream("pointreggpt_pair", recording_id=f"pair-{pair.get('pair_key', '')}")
    images = [name for column, name in IMAGE_COLUMNS if pair.get(column)]
    blueprint = _blueprint(rrb, images)
    if save is not None:
        rec.save(os.fspath(save), default_blueprint=blueprint)
    else:
        rec.spawn(default_blueprint=blueprint)
    log_pair(pair, rec)
    rec.flush()
    if save is not None:
        rec.disconnect()
        print(f"wrote {save}: open it with `rerun {save}`", file=sys.stderr)
        return os.fspath(save)
    return None


__all__ = ["show_pair", "log_pair", "provenance_kinds", "target_in_source_frame", "has_display", "KINDS", "IMAGE_COLUMNS"]
