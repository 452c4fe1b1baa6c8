# Project-wide helpers: warnings, sanitizers, tests, subdirectories that may not exist yet.

# Warnings for the project's own targets (not for third-party code).
function(dance_target_warnings target)
  target_compile_options(${target} PRIVATE -Wall -Wextra -Wpedantic -Wno-unused-parameter
                         $<$<CXX_COMPILER_ID:GNU>:-Wshadow=local>)  # clang has no -Wshadow=local
  if(DANCE_WERROR)
    target_compile_options(${target} PRIVATE -Werror)
  endif()
endfunction()

macro(dance_configure_sanitizers)
  if(DANCE_SANITIZE STREQUAL "address")
    add_compile_options(-fsanitize=address,undefined -fno-omit-frame-pointer -fno-sanitize-recover=undefined)
    add_link_options(-fsanitize=address,undefined)
  elseif(DANCE_SANITIZE STREQUAL "thread")
    add_compile_options(-fsanitize=thread -fno-omit-frame-pointer)
    add_link_options(-fsanitize=thread)
    # Debian's abseil is not TSan-instrumented: every target links the absl::Mutex annotations
    # (cmake/tsan_absl_mutex.cc), and tests run with the narrow suppressions in cmake/tsan.supp.
    add_library(dance_tsan_absl_mutex OBJECT ${CMAKE_CURRENT_LIST_DIR}/cmake/tsan_absl_mutex.cc)
    link_libraries(dance_tsan_absl_mutex ${CMAKE_DL_LIBS})
    set(DANCE_TEST_ENV "TSAN_OPTIONS=suppressions=${CMAKE_CURRENT_LIST_DIR}/cmake/tsan.supp halt_on_error=1 second_deadlock_stack=1")
  elseif(NOT DANCE_SANITIZE STREQUAL "")
    message(FATAL_ERROR "DANCE_SANITIZE must be '', 'address' or 'thread', not '${DANCE_SANITIZE}'")
  endif()
endmacro()

# dance_add_test(NAME name SOURCES a.cc b.cc LIBS lib... LABELS unit|golden|integration|slow)
# Builds a GoogleTest binary and registers it with CTest, run from the source root so tests can read
# models/, tests/golden/ and ../shared/data by relative path.
function(dance_add_test)
  cmake_parse_arguments(T "" "NAME" "SOURCES;LIBS;LABELS" ${ARGN})
  add_executable(${T_NAME} ${T_SOURCES})
  target_link_libraries(${T_NAME} PRIVATE ${T_LIBS} GTest::gtest GTest::gtest_main)
  dance_target_warnings(${T_NAME})
  set_target_properties(${T_NAME} PROPERTIES RUNTIME_OUTPUT_DIRECTORY ${CMAKE_BINARY_DIR}/tests)
  add_test(NAME ${T_NAME} COMMAND ${T_NAME} WORKING_DIRECTORY ${PROJECT_SOURCE_DIR})
  if(NOT T_LABELS)
    set(T_LABELS unit)
  endif()
  set(env "DANCE_SOURCE_DIR=${PROJECT_SOURCE_DIR}" "DANCE_BINARY_DIR=${CMAKE_BINARY_DIR}" ${DANCE_TEST_ENV})
  set_tests_properties(${T_NAME} PROPERTIES LABELS "${T_LABELS}" ENVIRONMENT "${env}")
endfunction()

# Adds every listed subdirectory that has a CMakeLists.txt (parts of the tree land one at a time).
function(dance_add_existing_subdirectories)
  foreach(dir ${ARGN})
    if(EXISTS ${CMAKE_CURRENT_SOURCE_DIR}/${dir}/CMakeLists.txt)
      add_subdirectory(${dir})
    endif()
  endforeach()
endfunction()

# Target CPU for x86-64 builds. The engine's GEMMs (Eigen) and the audio front end are several times
# faster with AVX2 + FMA than with the baseline x86-64 (SSE2) that compilers target by default.
# DANCE_X86_64_LEVEL: "x86-64-v3" (AVX2, FMA, F16C, BMI; every x86 server CPU since ~2015; the default),
# "x86-64-v4" (adds AVX-512), "native", or "" / OFF for the compiler's default (portable binaries).
# -ffp-contract=off keeps scalar code from being fused into FMAs behind our back, so scalar arithmetic
# (beat tracker, PRE, sampling) rounds the same with or without the flag; Eigen and our kernels use
# explicit FMA instructions where they want them.
macro(dance_configure_cpu_flags)
  if(CMAKE_SYSTEM_PROCESSOR MATCHES "^(x86_64|AMD64|amd64)$")
    set(DANCE_X86_64_LEVEL "x86-64-v3" CACHE STRING
        "x86-64 target level: x86-64-v3 (AVX2+FMA, default), x86-64-v4, native, or empty for the compiler default")
    if(DANCE_X86_64_LEVEL AND NOT DANCE_X86_64_LEVEL STREQUAL "OFF")
      include(CheckCXXCompilerFlag)
      check_cxx_compiler_flag("-march=${DANCE_X86_64_LEVEL}" DANCE_HAVE_MARCH_${DANCE_X86_64_LEVEL})
      if(DANCE_HAVE_MARCH_${DANCE_X86_64_LEVEL})
        add_compile_options(-march=${DANCE_X86_64_LEVEL})
      else()
        message(WARNING "compiler does not accept -march=${DANCE_X86_64_LEVEL}; using its default target")
      endif()
    endif()
  endif()
  add_compile_options(-ffp-contract=off)
endmacro()
# Applied to every target of the project (this file is included by the top-level CMakeLists.txt before
# any target is defined).
dance_configure_cpu_flags()
