# Project-wide helpers: warnings, sanitizers, tests, subdirectories that may not exist yet.

# Warnings for the project's own targets (not for third-party code).
function(dance_target_warnings target)
  target_compile_options(${target} PRIVATE -Wall -Wextra -Wpedantic -Wshadow=local -Wno-unused-parameter)
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
  set_tests_properties(${T_NAME} PROPERTIES LABELS "${T_LABELS}"
    ENVIRONMENT "DANCE_SOURCE_DIR=${PROJECT_SOURCE_DIR};DANCE_BINARY_DIR=${CMAKE_BINARY_DIR}")
endfunction()

# Adds every listed subdirectory that has a CMakeLists.txt (parts of the tree land one at a time).
function(dance_add_existing_subdirectories)
  foreach(dir ${ARGN})
    if(EXISTS ${CMAKE_CURRENT_SOURCE_DIR}/${dir}/CMakeLists.txt)
      add_subdirectory(${dir})
    endif()
  endforeach()
endfunction()
