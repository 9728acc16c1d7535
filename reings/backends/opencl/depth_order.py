"""The depth orders of `OpenCLBackend`: one depth sort shared by the forwards that rank the
Gaussians the same way (docs/perf_notes.md §9).

    mode = depth_order_setting(None)        # "share" (default) | "sort"; REINGS_DEPTH_ORDER overrides
    orders = DepthOrders(scratch)           # ORDERS sorted (keys, gid_from_rank) pairs, each with a tag
    o = orders.find(tag)                    # an order sorted under `tag` (None: none, or tag None)
    o = orders.claim(held, n)               # the least recently used order no live frame holds,
    ...sort into (o.keys, o.gids)...        # untagged, its generation bumped; then
    o.tag = tag                             # once the sort is enqueued

Why an order can be shared: project_fwd's depth key is the float bits of t_z where t_z > near, the
sentinel elsewhere (the near-plane test only, kernels/project.cl), so the sorted (key, gid) pairs
are a function of the means, the camera's z row (R[2, :], t_z), near and N, and of nothing that
culls a Gaussian otherwise (frustum, radius, determinant, tile rect, DropGaussian's mask, the
opacity override). The stable sort restricted to the visible Gaussians is their own stable
(t_z, gid) order, and the ranks culled otherwise have empty tile rects (bin_count gives them no
tile), so a forward bound to a shared order bins, rasterizes and backpropagates the bits of one
that sorted its own keys (kernels/bin.cl).

Who says that two forwards rank the same way: the caller, with an order key (`forward_device(...,
order_key=)`; None = always sort, the default of every public path). The device trainer's key is
(its geometry version, bumped on every write of the means buffer; the camera's viewmat row 2 as
float32 bytes; near as float32): reings/backends/opencl/trainer.py. The backend adds N and the SH
count (the projection program's variant) to make the tag.

Lifetimes (safe by construction): an order is re-sorted (`claim`) only when no live frame holds it.
The live frames are the current frame of each frame slot (slot 0: until the next forward into it;
slot 1, the kept frame: until the next forward with keep=True), so at any forward at most one
other frame holds an order, and two orders would always leave one to claim. Of the free ones the
least recently used (sorted into or shared) is claimed, and ORDERS = 3: a slot-0 forward of
another camera (the cross_warp partner) then leaves the order that the photometric pass will share
alone even while a kept frame holds a third (the kept frame of an earlier iteration, or of an
earlier fit on the same backend). Any frame may borrow and lend: the kept virtual view shares the
soft pass's order, the photometric pass the virtual view's. A frame records its order's
generation; its backward checks it (`OpenCLBackend._raster_bwd_buffers`) and raises if the order
was re-sorted since the forward, which this scheme never does.

Sorts per iteration in the training loop, before -> after (view_warp on):
    coarse (hard depth, means step, virtual view, photometric):  3 -> 2
    fine / final (soft depth, opacity step, virtual view, photometric):  3 -> 1
    + the cross_warp occlusion partner (another camera, a slot-0 forward between the kept
      frame's forward and its backward):  coarse 4 -> 3, fine 4 -> 2
    soft_depth_shared (virtual view, photometric with the soft term):  2 -> 1
    bench/bench_host.py (hard, means step, soft, virtual, photometric):  4 -> 2
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

DEPTH_ORDERS = ("share", "sort")
DEPTH_ORDER_DEFAULT = "share"  # bit-identical to "sort" (tests/test_depth_order.py)
DEPTH_ORDER_ENV = "REINGS_DEPTH_ORDER"  # overrides the default of a backend made without one
ORDERS = 3  # sorted orders kept: the two frame slots' and the last sorted one (module docstring, "Lifetimes")


def depth_order_setting(mode: str | None) -> str:
    """A backend's depth order mode: `mode`, else $REINGS_DEPTH_ORDER, else "share"; checked.
    "share": a forward with an order key equal to a kept order's binds to it (no sort); "sort":
    every forward sorts (the measurement baseline)."""
    from .bin_counts import choice_setting

    return choice_setting(mode, "depth_order", DEPTH_ORDER_ENV, DEPTH_ORDER_DEFAULT, DEPTH_ORDERS)


@dataclass
class Order:
    """One sorted depth order: the sorted keys and gid_from_rank ([n] uint32 each, in buffers that
    no projection writes), the tag it was sorted under (None: not shareable), its generation
    (bumped by every sort into it) and when it was last used (DepthOrders' clock)."""

    name: str
    keys: Any = None
    gids: Any = None
    tag: Any = None
    gen: int = 0
    used: int = 0


class DepthOrders:
    """The backend's ORDERS orders (module docstring); buffers from the backend's Scratch, named
    "<order name>_keys" / "_gids" in the gauss space."""

    def __init__(self, scratch, count: int = ORDERS):
        self.scratch = scratch
        self.orders = [Order(f"depth_order{i}") for i in range(count)]
        self.clock = 0

    def _use(self, o: Order) -> Order:
        self.clock += 1
        o.used = self.clock
        return o

    def find(self, tag) -> Order | None:
        """The order sorted under `tag` (marked used), or None (always None for tag None)."""
        if tag is None:
            return None
        for o in self.orders:
            if o.tag == tag:
                return self._use(o)
        return None

    def claim(self, held, n: int) -> Order:
        """The least recently used order that none of `held` (the orders of the live frames) is,
        for a sort of n pairs: buffers of n pairs, the tag cleared (the caller tags it once its
        sort is enqueued), the generation bumped (frames bound to its earlier contents, none of
        them live, can no longer be backpropagated)."""
        free = [o for o in self.orders if not any(o is h for h in held)] if held else list(self.orders)
        if not free:  # cannot happen with ORDERS >= the frame slots (module docstring)
            raise RuntimeError(f"depth orders: all {len(self.orders)} are held by live frames")
        o = min(free, key=lambda o: o.used)
        o.keys = self.scratch.get("gauss", f"{o.name}_keys", n, 4)
        o.gids = self.scratch.get("gauss", f"{o.name}_gids", n, 4)
        o.tag, o.gen = None, o.gen + 1
        return self._use(o)
