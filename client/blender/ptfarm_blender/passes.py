"""The render passes the panel offers, as Cycles' View Layer > Passes
names them, and the farm's pass names each one asks for (ptworker --help,
--passes; common/render/passes.h). Without Blender: a table and a function.

The panel shows one checkbox per row of PASSES and nothing else about
passes, so what reaches `ptctl submit --passes` is always a list of names
from this table: no pass the farm does not know can be asked for.

Threads: pure data; any thread.
"""

# The farm's names, in the order ptworker writes them (pt_passes_text).
FARM_ORDER = ("albedo", "normal", "depth", "emission", "halves", "cryptomatte")

# (property, label, heading in the panel, farm passes, tooltip). A tooltip
# says what the layers hold, by the names the EXR gives them (Blender's
# Image Editor and compositor list them as passes of the image).
PASSES = (
    ("use_pass_denoising_data", "Denoising Data", "Passes",
     ("albedo", "normal", "depth", "halves"),
     "The layers a denoiser reads (ptdenoise needs all of them): albedo (the reflectance of "
     "the first non-specular surface, seen through mirrors and smooth glass with their "
     "tint), N (that surface's shading normal), depth (camera distance of the first hit) "
     "and halfA, halfB (the image over the even and over the odd samples), each with its "
     "variance"),
    ("use_pass_normal", "Normal", "Passes", ("normal",),
     "Layer N (X, Y, Z): the shading normal of the first non-specular surface, in world "
     "space, turned to face the camera ray (as Cycles' Denoising Normal: seen through "
     "mirrors and smooth glass), with N.variance"),
    ("use_pass_z", "Z", "Passes", ("depth",),
     "Layer depth (Z): the distance from the camera to the first surface a ray hits, in "
     "scene units, 0 where the ray escapes (Cycles' Z), with depth.variance"),
    ("use_pass_emission", "Emission", "Passes", ("emission",),
     "Layer emission (R, G, B): the radiance the first surface hit emits itself (Cycles' "
     "Emission), with emission.variance"),
    ("use_pass_cryptomatte_object", "Object", "Cryptomatte", ("cryptomatte",),
     "Cryptomatte layers CryptoObject00-03: which objects cover each pixel and how much, "
     "for mattes in the compositor's Cryptomatte node. The farm renders objects and "
     "materials as one pass: this ticks Material too"),
    ("use_pass_cryptomatte_material", "Material", "Cryptomatte", ("cryptomatte",),
     "Cryptomatte layers CryptoMaterial00-03: which materials cover each pixel and how "
     "much, for mattes in the compositor's Cryptomatte node. The farm renders objects "
     "and materials as one pass: this ticks Object too"),
)

# Checkboxes that stand for the same farm pass and so tick together.
LINKED = {
    "use_pass_cryptomatte_object": "use_pass_cryptomatte_material",
    "use_pass_cryptomatte_material": "use_pass_cryptomatte_object",
}


def farm_passes(settings):
    """The farm's pass names the ticked checkboxes of settings (anything
    with the PASSES properties as attributes) ask for, in FARM_ORDER,
    each once; [] for none."""
    asked = set()
    for prop, _label, _heading, names, _tip in PASSES:
        if getattr(settings, prop):
            asked.update(names)
    return [n for n in FARM_ORDER if n in asked]
