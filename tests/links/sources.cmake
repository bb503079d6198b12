# Tests of the link algorithms and link plugins.
