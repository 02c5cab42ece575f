"""What differs between the Blender releases CubeGI supports (4.5 LTS through 5.3), in one
place. Each entry names the versions and the reason, measured with ``bpy`` from PyPI on Mesa
llvmpipe (OpenGL 4.5 through EGL); ``docs/blender-versions.md`` has the table.

Everything else in the add-on is written once for every supported version.
"""

import bpy
import numpy as np

# The oldest release CubeGI is tested on (the manifest's ``blender_version_min``). 4.2 cannot
# register: its ``StringProperty`` lacks the ``PATH_SUPPORTS_BLEND_RELATIVE`` option.
MIN_VERSION = (4, 5, 0)


def gpu_buffer_array(buf, shape):
    """A ``gpu.types.Buffer`` (as ``GPUTexture.read()`` returns) as a float32 array of
    ``shape`` in the buffer's own memory order (row 0 first), without a copy.

    The buffer's memory is row-major on every version, but up to 5.1 its buffer protocol
    declared the strides reversed (first axis fastest, ``pygpu_buffer_strides_calc``), so
    ``np.asarray`` saw a transposed array; 5.2 declares them row-major. Reading the elements
    in memory order (``order="K"``) is right under either declaration, so one path serves all
    versions; the capture test checks it against a known pattern on each.
    """
    return np.asarray(buf, dtype=np.float32).ravel(order="K").reshape(shape)


def shader_columns(shader, columns):
    """The vertex ``columns`` (name -> array) that ``shader`` declares as inputs.

    A vertex input that a shader never reads is dropped by the GLSL compiler up to 5.2, and
    ``batch_for_shader`` then refuses a column of that name; 5.3 keeps the input, and
    refuses a batch without it (``KeyError``). Asking the shader which inputs it has serves
    both.
    """
    declared = {name for name, _type in shader.attrs_info_get()}
    return {name: data for name, data in columns.items() if name in declared}


def light_node_tree(light):
    """The node tree a render uses for a light's data, or None.

    Up to 5.0 a light uses its nodes only with Use Nodes on (off by default); from 5.1 it
    always does, and reading ``use_nodes`` is deprecated (it reads True; to be removed in
    6.0).
    """
    if bpy.app.version >= (5, 1, 0):
        return light.node_tree
    return light.node_tree if light.use_nodes else None
