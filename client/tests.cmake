# Client tests (included from tests/CMakeLists.txt, so hs_add_test and the tests folder apply).
hs_add_test(client hapsim_client)
set_tests_properties(client PROPERTIES TIMEOUT 60)
hs_add_test(client_view hs_view)
set_tests_properties(client_view PROPERTIES TIMEOUT 60)
# VTK output read back by meshio / Python's XML parser (not our code).
add_test(NAME client_vtk COMMAND ${CMAKE_CURRENT_SOURCE_DIR}/test_client_vtk.sh
         $<TARGET_FILE:test_client_view>)
set_tests_properties(client_vtk PROPERTIES TIMEOUT 60 SKIP_RETURN_CODE 77)
# Install into a temporary prefix; build consumers with find_package(hapsim) and pkg-config.
add_test(NAME client_install COMMAND ${CMAKE_CURRENT_SOURCE_DIR}/test_client_install.sh
         ${PROJECT_BINARY_DIR})
set_tests_properties(client_install PROPERTIES TIMEOUT 60)
