# Debian's SuiteSparse 5.x ships no CMake config and LCM's pkg-config file needs glib's:
# find headers and libraries directly.
find_package(Threads REQUIRED)

find_path(CHOLMOD_INCLUDE_DIR cholmod.h PATH_SUFFIXES suitesparse)
find_library(CHOLMOD_LIBRARY cholmod)
find_library(SUITESPARSECONFIG_LIBRARY suitesparseconfig)
if(NOT CHOLMOD_INCLUDE_DIR OR NOT CHOLMOD_LIBRARY)
  message(FATAL_ERROR "CHOLMOD not found: apt-get install libsuitesparse-dev libopenblas-dev")
endif()
add_library(hs_cholmod INTERFACE)
target_include_directories(hs_cholmod SYSTEM INTERFACE ${CHOLMOD_INCLUDE_DIR})
target_link_libraries(hs_cholmod INTERFACE ${CHOLMOD_LIBRARY} ${SUITESPARSECONFIG_LIBRARY})
add_library(SuiteSparse::CHOLMOD ALIAS hs_cholmod)

find_path(LCM_INCLUDE_DIR lcm/lcm.h)
find_library(LCM_LIBRARY lcm)
find_program(LCM_GEN lcm-gen)
if(LCM_INCLUDE_DIR AND LCM_LIBRARY AND LCM_GEN)
  add_library(hs_lcm INTERFACE)
  target_include_directories(hs_lcm SYSTEM INTERFACE ${LCM_INCLUDE_DIR})
  target_link_libraries(hs_lcm INTERFACE ${LCM_LIBRARY})
  add_library(lcm::lcm ALIAS hs_lcm)
  set(HS_HAVE_LCM ON)
else()
  message(FATAL_ERROR "LCM not found: apt-get install liblcm-dev liblcm-bin")
endif()

find_library(M_LIBRARY m)
