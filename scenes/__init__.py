"""Built-in spectral scenes and cube loading for the simulator.

Every scene is a function ``(shape=(H, W), wavelengths=…, **params) -> cube`` returning relative
spectral radiance (H, W, L) float32 (reflectance × illuminant, illuminant peak 1). Use
:func:`scenes.registry.get_scene` to build one by name or to load a cube file.
"""
