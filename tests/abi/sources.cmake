# Test sources of tests/abi (paths relative to tests/).
