# Client tests (included from tests/CMakeLists.txt, so hs_add_test and the tests folder apply).
hs_add_test(client hapsim_client)
set_tests_properties(client PROPERTIES TIMEOUT 60)
