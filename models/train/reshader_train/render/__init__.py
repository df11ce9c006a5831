"""Dataset rendering with Mitsuba 3: input / reshaded / novel views, depth and validity mask.

Modules that need Mitsuba import it through `mitsuba_env.load_mitsuba()`, which locates
a suitable libLLVM first; the rest (cameras, textures, scene parameters) is plain numpy.
"""
