import sys
import mitsuba as mi
mi.set_variant("llvm_ad_rgb")
import numpy as np
import integrators
from episcatter.motion import parse_motion
from episcatter.sequence import Sequence
from tests.test_sequence import MOTIONS, animated_scene, full_render
method = sys.argv[1]
res = tuple(map(int, sys.argv[2].split("x")))
for light in sys.argv[3:]:
    for motion in ("translate", "rotate", "wave"):
        scene = animated_scene(light, res)
        seq = Sequence(scene, mi.load_dict({"type": method}), [parse_motion(MOTIONS[motion])], frames=4, keep_mask=True)
        prev = None
        for frame in seq:
            full = full_render(scene, mi.load_dict({"type": method}))
            err = max(np.abs(frame.layers[n] - full[n]).max() / max(full[n].max(), 1e-30) for n in full)
            missed = -1
            if prev is not None:
                changed = np.any(full["scattering"] != prev["scattering"], axis=2).ravel()
                changed |= np.any(full["distance"] != prev["distance"], axis=2).ravel()
                missed = np.count_nonzero(changed & ~frame.mask)
            print(light, motion, frame.index, f"{frame.recomputed}/{frame.samples}", frame.whole_frame, f"err {err:.2e} missed {missed}", flush=True)
            prev = full
