# SPDX-License-Identifier: GPL-2.0-or-later
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
# The partial refactorisation calls LAPACK / BLAS directly (the ones CHOLMOD links).
find_library(LAPACK_LIBRARY lapack)
find_library(BLAS_LIBRARY NAMES blas openblas)
if(NOT LAPACK_LIBRARY OR NOT BLAS_LIBRARY)
  message(FATAL_ERROR "LAPACK/BLAS not found: apt-get install libopenblas-dev")
endif()

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

# cJSON (Debian libcjson-dev) for scene files.
find_path(CJSON_INCLUDE_DIR cJSON.h PATH_SUFFIXES cjson)
find_library(CJSON_LIBRARY cjson)
if(NOT CJSON_INCLUDE_DIR OR NOT CJSON_LIBRARY)
  message(FATAL_ERROR "cJSON not found: apt-get install libcjson-dev")
endif()
add_library(hs_cjson INTERFACE)
target_include_directories(hs_cjson SYSTEM INTERFACE ${CJSON_INCLUDE_DIR})
target_link_libraries(hs_cjson INTERFACE ${CJSON_LIBRARY})
add_library(cJSON::cJSON ALIAS hs_cjson)

# gmsh's C API (Debian libgmsh-dev, GPL-2.0-or-later) for hapsim-mesh's tetrahedralisation.
find_path(GMSH_INCLUDE_DIR gmshc.h)
find_library(GMSH_LIBRARY gmsh)
if(NOT GMSH_INCLUDE_DIR OR NOT GMSH_LIBRARY)
  message(FATAL_ERROR "gmsh not found: apt-get install libgmsh-dev")
endif()
add_library(hs_gmsh INTERFACE)
target_include_directories(hs_gmsh SYSTEM INTERFACE ${GMSH_INCLUDE_DIR})
target_link_libraries(hs_gmsh INTERFACE ${GMSH_LIBRARY})
add_library(Gmsh::Gmsh ALIAS hs_gmsh)
