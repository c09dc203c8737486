#include <gtest/gtest.h>

#include <random>
#include <stdexcept>
#include <vector>

#include "forestslam/io/lzf.hpp"

using forestslam::io::lzfCompress;
using forestslam::io::lzfDecompress;
using Bytes = std::vector<std::uint8_t>;

TEST(Lzf, DecodesHandWrittenStream) {
    // "abc" as a literal run, then a back reference of length 7 at distance 3 -> "abcabcabca".
    const Bytes stream = {2, 'a', 'b', 'c', (5 << 5) | 0, 2};
    const Bytes out = lzfDecompress(stream.data(), stream.size(), 10);
    EXPECT_EQ(std::string(out.begin(), out.end()), "abcabcabca");
}

TEST(Lzf, DecodesLongReferenceWithExtraLengthByte) {
    // One literal 'x', then length 7 + 20 + 2 = 29 copies at distance 1: 30 'x' in total.
    const Bytes stream = {0, 'x', (7 << 5) | 0, 20, 0};
    const Bytes out = lzfDecompress(stream.data(), stream.size(), 30);
    EXPECT_EQ(out, Bytes(30, 'x'));
}

TEST(Lzf, RoundTripsRandomAndRepetitiveData) {
    std::mt19937 rng(7);
    std::uniform_int_distribution<int> byte(0, 255), small(0, 3);
    for (std::size_t n : {0u, 1u, 2u, 3u, 100u, 70000u}) {
        Bytes random(n), repetitive(n);
        for (std::size_t i = 0; i < n; ++i) {
            random[i] = static_cast<std::uint8_t>(byte(rng));
            repetitive[i] = static_cast<std::uint8_t>(small(rng) + (i % 50 == 0 ? 9 : 0));
        }
        for (const Bytes &data : {random, repetitive}) {
            const Bytes packed = lzfCompress(data.data(), data.size());
            EXPECT_EQ(lzfDecompress(packed.data(), packed.size(), data.size()), data) << n;
        }
    }
    Bytes zeros(100000, 0);
    const Bytes packed = lzfCompress(zeros.data(), zeros.size());
    EXPECT_LT(packed.size(), zeros.size() / 50);  // long runs must compress by references
}

TEST(Lzf, RejectsCorruptStreams) {
    const Bytes before_start = {0, 'a', (1 << 5) | 0, 5};  // distance 6 with 1 byte written
    EXPECT_THROW(lzfDecompress(before_start.data(), before_start.size(), 4), std::runtime_error);
    const Bytes short_literal = {5, 'a', 'b'};
    EXPECT_THROW(lzfDecompress(short_literal.data(), short_literal.size(), 6), std::runtime_error);
    const Bytes ok = {2, 'a', 'b', 'c'};
    EXPECT_THROW(lzfDecompress(ok.data(), ok.size(), 5), std::runtime_error);  // wrong size
    EXPECT_THROW(lzfDecompress(ok.data(), ok.size(), 2), std::runtime_error);  // overrun
}
