#include <pybind11/pybind11.h>

#include <stdexcept>
#include <string>

#include "bindings.hpp"
#include "forestslam/io/lzf.hpp"

namespace py = pybind11;

namespace forestslam::python {

void define_io(py::module_ &m) {
    m.def(
        "lzf_decompress",
        [](const py::bytes &data, std::size_t expected_size) {
            const std::string in = data;
            std::vector<std::uint8_t> out;
            try {
                py::gil_scoped_release release;
                out = lzfDecompress(reinterpret_cast<const std::uint8_t *>(in.data()), in.size(),
                                    expected_size);
            } catch (const std::runtime_error &err) {
                throw py::value_error(err.what());
            }
            return py::bytes(reinterpret_cast<const char *>(out.data()), out.size());
        },
        py::arg("data"), py::arg("expected_size"),
        "LZF stream (bytes) -> bytes of exactly expected_size; ValueError when corrupt.");
    m.def(
        "lzf_compress",
        [](const py::bytes &data) {
            const std::string in = data;
            std::vector<std::uint8_t> out;
            {
                py::gil_scoped_release release;
                out = lzfCompress(reinterpret_cast<const std::uint8_t *>(in.data()), in.size());
            }
            return py::bytes(reinterpret_cast<const char *>(out.data()), out.size());
        },
        py::arg("data"), "bytes -> LZF stream (liblzf format, as in PCD binary_compressed).");
}

}  // namespace forestslam::python
