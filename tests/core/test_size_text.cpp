// Sizes as users write them (`crpgs encode --target-size`).
#include <gtest/gtest.h>

#include "core/size_text.h"

namespace crpgs {
namespace {

TEST(SizeText, ReadsBytesAndBothKindsOfUnits) {
  EXPECT_EQ(parse_byte_size("2000000").value(), 2000000u);
  EXPECT_EQ(parse_byte_size("512B").value(), 512u);
  EXPECT_EQ(parse_byte_size("1.5MiB").value(), 1572864u);  // the field's "MB" is 2^20 bytes
  EXPECT_EQ(parse_byte_size("1.5 MiB").value(), 1572864u);
  EXPECT_EQ(parse_byte_size("800KiB").value(), 819200u);
  EXPECT_EQ(parse_byte_size("800KB").value(), 800000u);
  EXPECT_EQ(parse_byte_size("2MB").value(), 2000000u);
  EXPECT_EQ(parse_byte_size("1GiB").value(), 1073741824u);
}

TEST(SizeText, RefusesWhatIsNotASize) {
  for (const char* bad : {"", "MiB", "-1MiB", "0", "1.5mib", "1.5 megabytes", "nan", "1e30GB"}) {
    auto r = parse_byte_size(bad);
    ASSERT_FALSE(r.ok()) << bad;
    EXPECT_NE(r.status().message().find("is not a size"), std::string::npos) << bad;
  }
}

}  // namespace
}  // namespace crpgs
