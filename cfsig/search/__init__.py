"""Search: rank indexed shapes by distance to a whole query or to a part of a shape."""
