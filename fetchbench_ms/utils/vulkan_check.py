"""Exit 0 when SAPIEN can render with the Vulkan device found on this machine.

Run as ``python -m fetchbench_ms.utils.vulkan_check``. It renders in this process, so
call it in a subprocess: a missing or too old driver (Mesa lavapipe < 24.3) can abort
the interpreter instead of raising.
"""
import sys


def main() -> int:
    try:
        import numpy as np
        import sapien

        from fetchbench_ms.utils.sapien_device import new_scene

        scene = new_scene()
        camera = scene.add_camera("check", 32, 32, 1.0, 0.01, 10.0)
        scene.update_render()
        camera.take_picture()
        rgba = camera.get_picture("Color")
        assert np.asarray(rgba).shape[:2] == (32, 32)
    except Exception as error:  # any failure means "no usable renderer"
        print(f"no usable Vulkan renderer: {error}", file=sys.stderr)
        return 1
    print("SAPIEN renders with Vulkan")
    return 0


if __name__ == "__main__":
    sys.exit(main())
