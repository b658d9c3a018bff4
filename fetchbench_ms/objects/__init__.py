"""The object catalog (``catalog``): YCB scans, blobs and procedural objects with their
convex parts, mass and stable poses, and their loading for tasks (``loading``).

The catalog's statistics (``catalog.stats()``, ``fetchbench objects stats``) take extensions
registered here, without loading the catalog: functions ``f(stats_dict) -> None`` that add
their own keys (the grasp labels' counts, ``grasp_labels.store``), called in registration order;
one registered while they run (by a module an extension loads) is called in the same pass.
"""
STATS_EXTENSIONS: list = []


def register_stats_extension(function) -> None:
    if function not in STATS_EXTENSIONS:
        STATS_EXTENSIONS.append(function)
