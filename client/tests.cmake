# SPDX-License-Identifier: MIT
# Client tests (included from tests/CMakeLists.txt, so hs_add_test and the tests folder apply).
hs_add_test(client hapsim_client)
# White-box cases (the wire decoders' ranges) include the client's internal wire.h.
target_include_directories(test_client PRIVATE ${PROJECT_SOURCE_DIR}/client)
set_tests_properties(client PROPERTIES TIMEOUT 60)
# A pose-sending thread beside the polling one, on its own so that make test-tsan runs it.
add_test(NAME client_threads COMMAND test_client test_pose_thread)
set_tests_properties(client_threads PROPERTIES TIMEOUT 120 LABELS tsan)
hs_add_test(client_view hs_view)
set_tests_properties(client_view PROPERTIES TIMEOUT 60)
# VTK output read back by meshio / Python's XML parser (not our code).
add_test(NAME client_vtk COMMAND ${CMAKE_CURRENT_SOURCE_DIR}/test_client_vtk.sh
         $<TARGET_FILE:test_client_view>)
set_tests_properties(client_vtk PROPERTIES TIMEOUT 60 SKIP_RETURN_CODE 77)
# Install into a temporary prefix; build consumers with find_package(hapsim) and pkg-config.
set(HS_CONSUMER_SANITIZE "")
if(HS_SANITIZE)
  set(HS_CONSUMER_SANITIZE "-fsanitize=address,undefined")
elseif(HS_TSAN)
  set(HS_CONSUMER_SANITIZE "-fsanitize=thread")
endif()
add_test(NAME client_install COMMAND ${CMAKE_CURRENT_SOURCE_DIR}/test_client_install.sh
         ${PROJECT_BINARY_DIR} "${HS_CONSUMER_SANITIZE}")
set_tests_properties(client_install PROPERTIES TIMEOUT 60)
# End to end in a private network namespace: hapsim-server + hapsim-stylus + hapsim-view +
# hapsim-ctl (skipped, code 77, without a server build or network namespaces).
add_executable(test_client_press test_client_press.c)
target_link_libraries(test_client_press PRIVATE hs_view)
hs_set_warnings(test_client_press)
add_test(NAME client_e2e COMMAND ${CMAKE_CURRENT_SOURCE_DIR}/netns.sh
         ${CMAKE_CURRENT_SOURCE_DIR}/test_client_e2e.sh ${CMAKE_RUNTIME_OUTPUT_DIRECTORY}
         ${PROJECT_SOURCE_DIR})
set_tests_properties(client_e2e PROPERTIES TIMEOUT 60 SKIP_RETURN_CODE 77)
# hapsim-view / hapsim-ctl against a stand-in server publishing the liver (needs the mesh reader).
add_executable(test_client_fakesrv test_client_fakesrv.c)
target_link_libraries(test_client_fakesrv PRIVATE hs_mesh hapsim_msgs m)
add_test(NAME client_liver COMMAND ${CMAKE_CURRENT_SOURCE_DIR}/netns.sh
         ${CMAKE_CURRENT_SOURCE_DIR}/test_client_liver.sh ${CMAKE_RUNTIME_OUTPUT_DIRECTORY}
         ${PROJECT_SOURCE_DIR})
set_tests_properties(client_liver PROPERTIES TIMEOUT 60 SKIP_RETURN_CODE 77)
