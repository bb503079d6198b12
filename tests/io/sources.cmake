# Test sources of tests/io (paths relative to tests/).
