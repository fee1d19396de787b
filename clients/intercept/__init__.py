"""The interceptor, `track-intercept`: guidance on the display key space, and its report."""
