"""Few-shot train/test view selection, following each dataset's published protocol.

* LLFF (also NeX, COLMAP and the procedural scene): images sorted by name; test = positions
  i with i % 8 == 0; train = pool[round(j)] for j in numpy.linspace(0, len(pool) - 1, k), with
  Python's round (halves to even), pool = the other positions [RegNeRF/FreeNeRF, DNGaussian,
  FSGS: docs/method.md §4.1]. Deterministic, no seed.
* DTU: train = [25, 22, 28, 40, 44, 48, 0, 8, 13][:k], the 15 `DTU_EXCLUDED` ids are neither,
  the remaining 25 are test (the "pixelnerf" split, docs/method.md §4.2). Needs the 49 views.
* Blender (NeRF-synthetic): train = `BLENDER_TRAIN_IDS[:k]` among the `train` split (the 8-view
  DietNeRF/FreeNeRF list, quoted from memory), test = every `test` split image.

Indices are positions in `scene` (the order the loader produced). The train list keeps the
protocol's order (DTU's 25, 22, 28, ...); the test list is ascending.
"""
from __future__ import annotations

import numpy as np

DTU_TRAIN_IDS = [25, 22, 28, 40, 44, 48, 0, 8, 13]
DTU_EXCLUDED = [3, 4, 5, 6, 7, 16, 17, 18, 19, 20, 21, 36, 37, 38, 39]
BLENDER_TRAIN_IDS = [26, 86, 2, 55, 75, 93, 16, 73, 8]  # [MEMORY] FreeNeRF/DietNeRF 8-view list
LLFF_HOLDOUT = 8

_PROTOCOL_OF_KIND = {"llff": "llff", "llff_nex": "llff", "colmap": "llff", "nerfstudio": "llff", "procedural": "llff",
                     "dtu": "dtu", "blender": "blender"}


def llff_split(names: list[str], n_views: int, holdout: int = LLFF_HOLDOUT) -> tuple[list[int], list[int]]:
    """The LLFF rule on image `names`; indices refer to positions in `names`."""
    order = sorted(range(len(names)), key=lambda i: names[i])  # position in sorted order -> index
    test = [order[i] for i in range(len(order)) if i % holdout == 0]
    pool = [order[i] for i in range(len(order)) if i % holdout != 0]
    if not 1 <= n_views <= len(pool):
        raise ValueError(f"few_shot_split: n_views={n_views} but the LLFF train pool has {len(pool)} views")
    train = [pool[round(j)] for j in np.linspace(0, len(pool) - 1, n_views)]
    return train, sorted(test)


def dtu_split(n_views_total: int, n_views: int) -> tuple[list[int], list[int]]:
    if n_views_total != 49:
        raise ValueError(f"few_shot_split: the DTU protocol needs the 49 views of a scan, got {n_views_total}")
    if not 1 <= n_views <= len(DTU_TRAIN_IDS):
        raise ValueError(f"few_shot_split: DTU supports 1..{len(DTU_TRAIN_IDS)} views, got {n_views}")
    train = DTU_TRAIN_IDS[:n_views]
    skip = set(DTU_TRAIN_IDS) | set(DTU_EXCLUDED)
    test = [i for i in range(49) if i not in skip]
    return list(train), test


def blender_split(splits: list[str], n_views: int) -> tuple[list[int], list[int]]:
    tr = [i for i, s in enumerate(splits) if s == "train"]
    te = [i for i, s in enumerate(splits) if s == "test"]
    ids = BLENDER_TRAIN_IDS[:n_views] if n_views <= len(BLENDER_TRAIN_IDS) else list(range(n_views))
    if not tr or max(ids) >= len(tr):
        raise ValueError(f"few_shot_split: blender train split has {len(tr)} images, needs index {max(ids)}")
    return [tr[i] for i in ids], te


def few_shot_split(scene, n_views: int, protocol: str | None = None) -> tuple[list[int], list[int]]:
    """(train_indices, test_indices) into `scene` for `n_views` training views.

    `protocol` is "llff", "dtu" or "blender"; None follows `scene.kind`. Train and test are
    disjoint. Pass `scene.subset(train)` (and nothing else) to the training side.
    """
    n_views = int(n_views)
    proto = protocol or _PROTOCOL_OF_KIND.get(getattr(scene, "kind", ""), "llff")
    if proto == "llff":
        train, test = llff_split(list(scene.names), n_views)
    elif proto == "dtu":
        train, test = dtu_split(len(scene.names), n_views)
    elif proto == "blender":
        if getattr(scene, "splits", None) is None:
            raise ValueError("few_shot_split: blender protocol needs scene.splits")
        train, test = blender_split(list(scene.splits), n_views)
    else:
        raise ValueError(f"few_shot_split: unknown protocol {proto!r} (llff, dtu, blender)")
    assert not set(train) & set(test)
    return [int(i) for i in train], [int(i) for i in test]
