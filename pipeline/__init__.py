"""arroyo: stereo pairs of rock fields to depth maps, rock masks, descriptors and a scene graph.

The engine lives here; processing stages live in the sibling ``stages`` package.
"""

__version__ = "0.1.0"
