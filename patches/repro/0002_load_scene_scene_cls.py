"""0002: ``load_scene`` cannot build a ``Scene`` subclass.

Loads the bundled ``floor_wall`` scene (and the empty scene) with
``load_scene(..., scene_cls=MyScene)``.  Stock 2.2.0: ``TypeError``
(unexpected keyword argument).  Patched: the result is a ``MyScene`` with
both objects, and a non-``Scene`` class is rejected with ``TypeError``.
"""
from __future__ import annotations

from _common import report, setup

args, rt = setup(__doc__.splitlines()[0])


class MyScene(rt.Scene):
    """A subclass with extra state, as a downstream package would define."""

    def __init__(self, *a, **kw):
        self.extra = "mine"
        super().__init__(*a, **kw)


try:
    scene = rt.load_scene(rt.scene.floor_wall, scene_cls=MyScene)
    empty = rt.load_scene(scene_cls=MyScene)
except TypeError as e:
    report("0002 load_scene scene_cls", args.expect, "bug", f"TypeError: {e}")

ok = (type(scene) is MyScene and type(empty) is MyScene and scene.extra == "mine"
      and sorted(scene.objects) == ["floor", "wall"])
try:
    rt.load_scene(rt.scene.floor_wall, scene_cls=dict)
    rejected = False
except TypeError:
    rejected = True
observed = "fixed" if ok and rejected else "unexpected"
report("0002 load_scene scene_cls", args.expect, observed,
       f"load_scene returned {type(scene).__name__} with objects {sorted(scene.objects)}; "
       f"scene_cls=dict rejected: {rejected}")
