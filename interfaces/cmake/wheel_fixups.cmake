# The ROS wheels on PyPI export CMake targets that name include folders of the machine that
# built the wheels (its Python headers under /opt/python/...). CMake refuses a target that
# names a folder which does not exist, so at the end of configuring (after
# rosidl_generate_interfaces has found every dependency) each imported target's missing
# include folders are swapped for this interpreter's headers, or dropped.
find_package(Python3 REQUIRED COMPONENTS Interpreter Development.Module)

function(vigil_fix_wheel_targets)
  get_property(targets DIRECTORY PROPERTY IMPORTED_TARGETS)
  foreach(target IN LISTS targets)
    get_target_property(dirs ${target} INTERFACE_INCLUDE_DIRECTORIES)
    if(NOT dirs)
      continue()
    endif()
    set(fixed "")
    set(changed FALSE)
    foreach(dir IN LISTS dirs)
      if(dir MATCHES "^\\$<" OR EXISTS "${dir}")
        list(APPEND fixed "${dir}")
      else()
        set(changed TRUE)
        if(dir MATCHES "/include/python3")
          list(APPEND fixed ${Python3_INCLUDE_DIRS})
        endif()
      endif()
    endforeach()
    if(changed)
      list(REMOVE_DUPLICATES fixed)
      set_target_properties(${target} PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${fixed}")
    endif()
  endforeach()
endfunction()

cmake_language(DEFER CALL vigil_fix_wheel_targets)
