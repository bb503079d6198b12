# Test sources of tests/coding (paths relative to tests/).
