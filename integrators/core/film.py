"""The layers a render returns (``full``, ``scattering``, ``surface``,
``distance``): per-pixel averages of the camera samples, and their
development into Mitsuba's film and AOVs (DESIGN §4).
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi


OUTPUTS = ("full", "scattering")
#: the layers of render_layers() and their channels (film AOV names)
LAYERS = ("full", "scattering", "surface", "distance")
LAYER_CHANNELS = {"full": "RGB", "scattering": "RGB", "surface": "RGB", "distance": "Y"}


def layer_channels(layer: str) -> str:
    """The channel names of a layer in the active variant (one ``Y`` channel
    for every layer in ``*_mono`` variants)."""
    return "Y" if "mono" in mi.variant() else LAYER_CHANNELS[layer]


def develop_into_film(film, layers: dict, output: str, aovs: list) -> None:
    """Write the rendered layers into ``film``'s storage as Mitsuba's own
    integrators leave it after ``mi.render`` (``film.prepare`` + one image
    block): ``output`` as the colour, weight 1 (the box filter's pixel
    averages are final), alpha 1, then the ``aovs`` ("layer.C")."""
    channels = int(film.prepare(aovs))
    base = channels - 1 - len(aovs)          # colour (+ alpha); then weight, AOVs
    h, w, colour = layers[output].shape[0], layers[output].shape[1], layers[output].shape[2]
    if colour == 1 and base in (3, 4):       # a *_mono variant's RGB(A) film: Y as grey
        columns = [layers[output][..., 0]] * 3
        colour = 3
    elif base in (colour, colour + 1):
        columns = [layers[output][..., c] for c in range(colour)]
    else:
        raise ValueError(f"film '{film.class_name()}' with {base} colour/alpha channels is not "
                         "supported: use an RGB(A) hdrfilm.")
    ones = dr.full(mi.TensorXf, 1.0, (h, w))
    columns += [ones] * (base - colour) + [ones]     # alpha, weight
    for name in aovs:
        layer, channel = name.split(".")
        columns.append(layers[layer][..., layer_channels(layer).index(channel)])
    block = mi.ImageBlock(mi.TensorXf(dr.ravel(dr.stack(columns, axis=-1)),
                                      (h, w, channels)),
                          offset=film.crop_offset(), rfilter=film.rfilter(), border=False)
    film.put_block(block)


def pixel_average(values, pixel, n_pixels, spp):
    """Box filter: mean of each pixel's ``spp`` samples (``pixel``: each
    value's pixel; a subset capture's values leave the other pixels 0)."""
    if spp == 1 and dr.width(values) == n_pixels:
        return values
    out = dr.zeros(type(values), n_pixels)
    dr.scatter_reduce(dr.ReduceOp.Add, out, values, pixel)
    return out * (1.0 / spp)


def compose_layers(cap, L_scat, spp, mono=False, computed=None) -> dict:
    """The image layers of one render (DESIGN §1): ``full = T_cam·L_surface
    + L_scat``, ``scattering``, ``surface`` and ``distance``, each the box
    filter of its camera samples; ``computed`` (mi.Bool over the samples)
    zeroes the surface and distance of samples a partial render skipped."""
    n_pix = cap.width * cap.height
    T_L, d = cap.T_cam * cap.L_surface, cap.d
    if computed is not None:
        T_L, d = dr.select(computed, T_L, 0.0), dr.select(computed, d, 0.0)
    scat = pixel_average(L_scat, cap.pixel, n_pix, spp)
    surf = pixel_average(T_L, cap.pixel, n_pix, spp)
    dist = pixel_average(d, cap.pixel, n_pix, spp)
    w, h = cap.width, cap.height
    return {"full": to_image(surf + scat, w, h, mono), "scattering": to_image(scat, w, h, mono),
            "surface": to_image(surf, w, h, mono), "distance": to_image(dist, w, h)}


def to_image(values, width, height, mono=False):
    """Per-pixel Color3f/Float -> TensorXf (height, width, channels); with
    ``mono`` a Color3f keeps its first channel (the methods compute in
    Color3f; in a ``*_mono`` variant its three channels are equal)."""
    if isinstance(values, mi.Color3f):
        if mono:
            return mi.TensorXf(values.x, shape=(height, width, 1))
        flat = dr.ravel(values)
        return mi.TensorXf(flat, shape=(height, width, 3))
    return mi.TensorXf(values, shape=(height, width, 1))
