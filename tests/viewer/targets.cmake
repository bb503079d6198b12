# `crpgs view` in headless Chromium (viewer/view_test.py): the page loads and draws the scene as
# crpgs renders it. Skips (exit 77, a visible SKIP line) only where Chromium is absent or cannot
# start, or where scripts/setup recorded that npm could not install the viewer's packages. Python with numpy and PIL: Debian's /usr/bin/python3 (python3-torch, python3-pil).
if(TARGET crpgs_cli)
  if(PYTHON_EXECUTABLE)
    set(CRPGS_VIEWER_TEST_PYTHON ${PYTHON_EXECUTABLE})
  else()
    find_program(CRPGS_VIEWER_TEST_PYTHON NAMES python3 REQUIRED)
  endif()
  add_test(NAME viewer.chromium
    COMMAND ${CRPGS_VIEWER_TEST_PYTHON} ${CMAKE_CURRENT_SOURCE_DIR}/viewer/view_test.py
            ${PROJECT_BINARY_DIR} $<TARGET_FILE:crpgs_cli> ${PROJECT_SOURCE_DIR})
  set_tests_properties(viewer.chromium PROPERTIES SKIP_RETURN_CODE 77 TIMEOUT 900
    ENVIRONMENT "PYTHONDONTWRITEBYTECODE=1")
endif()
