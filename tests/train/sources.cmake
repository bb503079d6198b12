# Test sources of tests/train (paths relative to tests/).
