"""Furniture pieces (desks, bookcases, cell shelves, dressers, racks, baskets...) that the
scene types combine. Each piece declares its ``ParamSpec``s and a pure build function that
adds primitives and support surfaces to a ``SceneBuilder``."""
