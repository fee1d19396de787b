"""Plain textbook references the tests hold the service's fast paths against."""
