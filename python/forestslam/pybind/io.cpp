#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <algorithm>
#include <array>
#include <stdexcept>
#include <string>

#include "bindings.hpp"
#include "forestslam/io/lzf.hpp"
#include "forestslam/io/point_mask.hpp"

namespace py = pybind11;

namespace forestslam::python {

void define_io(py::module_ &m) {
    m.def(
        "real_point_indices",
        [](const py::array_t<std::uint8_t, py::array::c_style | py::array::forcecast> &data,
           std::size_t height, std::size_t width, std::size_t point_step, std::size_t row_step,
           const std::array<std::size_t, 3> &offsets, int scalar_bytes, bool big_endian) {
            io::XyzLayout layout;
            layout.height = height;
            layout.width = width;
            layout.point_step = point_step;
            layout.row_step = row_step;
            layout.offsets = offsets;
            layout.scalar_bytes = scalar_bytes;
            layout.big_endian = big_endian;
            std::vector<std::int64_t> idx;
            try {
                py::gil_scoped_release release;
                idx = io::realPointIndices(data.data(), static_cast<std::size_t>(data.size()),
                                           layout);
            } catch (const std::invalid_argument &err) {
                throw py::value_error(err.what());
            }
            py::array_t<std::int64_t> out(static_cast<py::ssize_t>(idx.size()));
            std::copy(idx.begin(), idx.end(), out.mutable_data());
            return out;
        },
        py::arg("data"), py::arg("height"), py::arg("width"), py::arg("point_step"),
        py::arg("row_step"), py::arg("offsets"), py::arg("scalar_bytes"), py::arg("big_endian"),
        "PointCloud2 data (uint8 buffer) -> (M,) int64 row-major indices of the points whose "
        "x, y, z (float32 or float64 at offsets) are finite and not all zero.");
    m.def(
        "lzf_decompress",
        [](const py::bytes &data, std::size_t expected_size) {
            const std::string in = data;
            std::vector<std::uint8_t> out;
            try {
                py::gil_scoped_release release;
                out = io::lzfDecompress(reinterpret_cast<const std::uint8_t *>(in.data()),
                                        in.size(), expected_size);
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
                out = io::lzfCompress(reinterpret_cast<const std::uint8_t *>(in.data()), in.size());
            }
            return py::bytes(reinterpret_cast<const char *>(out.data()), out.size());
        },
        py::arg("data"), "bytes -> LZF stream (liblzf format, as in PCD binary_compressed).");
}

}  // namespace forestslam::python
