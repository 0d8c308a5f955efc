"""Renderer for training and test data: procedural scenes and camera fly-throughs rendered with
Mitsuba 3 into per-sample frame files (``runtime.frames``).

Modules:
  variant    choose and initialise the Mitsuba variant (llvm_ad_rgb when a usable LLVM exists);
  camera     numpy camera model (Mitsuba's perspective/thinlens conventions) and camera paths;
  procedural numpy-only scene generator: meshes, textures, materials, lights, camera;
  materials  per-shape material table read back from a loaded Mitsuba scene;
  renderer   per-frame rendering: sample passes, guides, motion, visibility, reference;
  command    the ``mcdenoise render`` command.

Mitsuba is imported inside functions only, so importing this package (or ``mcdenoise --help``)
works on a machine without it.
"""
