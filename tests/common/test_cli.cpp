#include <gtest/gtest.h>

#include "rekon/common/cli.hpp"
#include "rekon/common/error.hpp"

namespace {
bool parse(rekon::ArgParser& p, std::vector<std::string> args) {
  std::vector<char*> argv;
  for (auto& a : args) argv.push_back(a.data());
  return p.parse(static_cast<int>(argv.size()), argv.data());
}
}  // namespace

TEST(ArgParser, OptionsFlagsRepeatedAndPositionals) {
  rekon::ArgParser p("prog", "test");
  p.option("out", "o", "x").flag("json", "j").repeated("set", "s").positional("GT", "g");
  ASSERT_TRUE(parse(p, {"prog", "gt.txt", "--out=dir", "--json", "--set", "a=1", "--set", "b=2"}));
  EXPECT_EQ(p.get("GT"), "gt.txt");
  EXPECT_EQ(p.get("out"), "dir");
  EXPECT_TRUE(p.flagSet("json"));
  EXPECT_EQ(p.all("set").size(), 2u);
}

TEST(ArgParser, UnknownOptionMissingValueAndMissingPositionalAreErrors) {
  rekon::ArgParser a("prog", "test");
  a.option("out", "o");
  EXPECT_THROW(parse(a, {"prog", "--nope"}), rekon::Error);
  rekon::ArgParser b("prog", "test");
  b.option("out", "o");
  EXPECT_THROW(parse(b, {"prog", "--out"}), rekon::Error);
  rekon::ArgParser c("prog", "test");
  c.positional("X", "x");
  EXPECT_THROW(parse(c, {"prog"}), rekon::Error);
}

TEST(ArgParser, NonNumericValueIsAnError) {
  rekon::ArgParser p("prog", "test");
  p.option("frames", "n", "10");
  ASSERT_TRUE(parse(p, {"prog", "--frames", "ten"}));
  EXPECT_THROW(p.getInt("frames"), rekon::Error);
}
