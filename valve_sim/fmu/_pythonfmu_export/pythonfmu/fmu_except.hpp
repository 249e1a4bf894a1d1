
#ifndef PYTHONFMU_FMU_EXCEPT_HPP
#define PYTHONFMU_FMU_EXCEPT_HPP

#include <stdexcept>
#include <string>

namespace pythonfmu {

    class fatal_error final : public std::runtime_error {
    public:
        explicit fatal_error(const std::string &msg) : std::runtime_error(msg) {}
    };

    // valve_sim: a Python exception in an FMI call; fmi2Error, the instance kept.
    class py_error final : public std::runtime_error {
    public:
        explicit py_error(const std::string &msg) : std::runtime_error(msg) {}
    };


}// namespace pythonfmu

#endif//PYTHONFMU_FMU_EXCEPT_HPP
