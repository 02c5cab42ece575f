"""CubeGI: diffuse global illumination from a grid of cube-map light probes, baked into
per-vertex colour attributes. The extension's entry point; see README.md."""


def register():
    from . import cubegi_addon

    cubegi_addon.register()


def unregister():
    from . import cubegi_addon

    cubegi_addon.unregister()
