#include "forestslam/io/lzf.hpp"

#include <algorithm>
#include <cstring>
#include <stdexcept>
#include <string>

namespace forestslam::io {

namespace {
constexpr std::size_t kMaxLiteral = 32;         // control byte 0..31 = run of 1..32 literals
constexpr std::size_t kMaxOffset = 1u << 13;    // 13-bit back-reference distance
constexpr std::size_t kMaxMatch = 7 + 255 + 2;  // length code 7 plus an extra byte, plus 2
constexpr unsigned kHashBits = 14;

[[noreturn]] void corrupt(const char *what, std::size_t at) {
    throw std::runtime_error(std::string("corrupt LZF stream: ") + what + " at input byte " +
                             std::to_string(at));
}

inline std::uint32_t hash3(const std::uint8_t *p) {
    const std::uint32_t v = (std::uint32_t(p[0]) << 16) | (std::uint32_t(p[1]) << 8) | p[2];
    return (v * 2654435761u) >> (32 - kHashBits);
}
}  // namespace

std::vector<std::uint8_t> lzfDecompress(const std::uint8_t *in, std::size_t in_size,
                                        std::size_t expected_size) {
    std::vector<std::uint8_t> out(expected_size);
    std::size_t ip = 0, op = 0;
    while (ip < in_size) {
        const std::size_t ctrl = in[ip++];
        if (ctrl < kMaxLiteral) {
            const std::size_t len = ctrl + 1;
            if (ip + len > in_size) corrupt("literal run past the end", ip);
            if (op + len > expected_size) corrupt("output overrun", ip);
            std::memcpy(out.data() + op, in + ip, len);
            ip += len;
            op += len;
            continue;
        }
        std::size_t len = ctrl >> 5;
        if (len == 7) {
            if (ip >= in_size) corrupt("truncated length", ip);
            len += in[ip++];
        }
        if (ip >= in_size) corrupt("truncated reference", ip);
        const std::size_t back = ((ctrl & 0x1f) << 8) + in[ip++] + 1;
        len += 2;
        if (back > op) corrupt("reference before the start", ip);
        if (op + len > expected_size) corrupt("output overrun", ip);
        // Overlapping copy on purpose: a reference may repeat the bytes it is producing.
        const std::uint8_t *ref = out.data() + op - back;
        for (std::size_t k = 0; k < len; ++k) out[op + k] = ref[k];
        op += len;
    }
    if (op != expected_size) corrupt("stream shorter than the declared size", ip);
    return out;
}

std::vector<std::uint8_t> lzfCompress(const std::uint8_t *in, std::size_t in_size) {
    std::vector<std::uint8_t> out;
    out.reserve(in_size + in_size / kMaxLiteral + 16);
    std::vector<std::int64_t> table(std::size_t(1) << kHashBits, -1);
    std::size_t literal_start = 0;  // first byte not yet emitted
    auto flush_literals = [&](std::size_t end) {
        while (literal_start < end) {
            const std::size_t len = std::min(kMaxLiteral, end - literal_start);
            out.push_back(static_cast<std::uint8_t>(len - 1));
            out.insert(out.end(), in + literal_start, in + literal_start + len);
            literal_start += len;
        }
    };
    std::size_t ip = 0;
    while (ip + 2 < in_size) {
        const std::uint32_t h = hash3(in + ip);
        const std::int64_t cand = table[h];
        table[h] = static_cast<std::int64_t>(ip);
        if (cand >= 0 && ip - static_cast<std::size_t>(cand) <= kMaxOffset &&
            std::memcmp(in + cand, in + ip, 3) == 0) {
            const std::size_t ref = static_cast<std::size_t>(cand);
            const std::size_t limit = std::min(kMaxMatch, in_size - ip);
            std::size_t len = 3;
            while (len < limit && in[ref + len] == in[ip + len]) ++len;
            flush_literals(ip);
            const std::size_t back = ip - ref - 1;
            const std::size_t code = len - 2;
            if (code < 7) {
                out.push_back(static_cast<std::uint8_t>((code << 5) | (back >> 8)));
            } else {
                out.push_back(static_cast<std::uint8_t>((7 << 5) | (back >> 8)));
                out.push_back(static_cast<std::uint8_t>(code - 7));
            }
            out.push_back(static_cast<std::uint8_t>(back & 0xff));
            for (std::size_t k = 1; k < len && ip + k + 2 < in_size; ++k)
                table[hash3(in + ip + k)] = static_cast<std::int64_t>(ip + k);
            ip += len;
            literal_start = ip;
        } else {
            ++ip;
        }
    }
    flush_literals(in_size);
    return out;
}

}  // namespace forestslam::io
