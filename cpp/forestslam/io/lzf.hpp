#pragma once
// LZF compression in the liblzf stream format, as PCL writes `DATA binary_compressed` PCD files.
#include <cstddef>
#include <cstdint>
#include <vector>

namespace forestslam::io {

/// Decompress an LZF stream that must expand to exactly `expected_size` bytes.
/// Throws std::runtime_error on a corrupt stream (back reference before the start, output
/// overrun, truncated literal or reference, or a size other than `expected_size`).
std::vector<std::uint8_t> lzfDecompress(const std::uint8_t *in, std::size_t in_size,
                                        std::size_t expected_size);

/// Compress to an LZF stream (greedy, 3-byte hash, window 8 KiB) that lzfDecompress and
/// liblzf/PCL read back.
std::vector<std::uint8_t> lzfCompress(const std::uint8_t *in, std::size_t in_size);

}  // namespace forestslam::io
