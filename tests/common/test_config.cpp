#include <gtest/gtest.h>

#include <fstream>

#include "rekon/common/config.hpp"
#include "rekon/common/error.hpp"
#include "test_support.hpp"

using rekon::Config;

TEST(Config, DefaultsComeFromTheEmbeddedDefaultYaml) {
  const Config c = Config::load();
  EXPECT_EQ(c.getString("lcm.channel_prefix"), "REKON_");
  EXPECT_EQ(c.getInt("transport.slots"), 8);
}

TEST(Config, FileAndSetOverridesApplyInOrder) {
  rekon::test::TempDir dir;
  std::ofstream(dir / "c.yaml") << "transport:\n  slots: 4\n";
  const Config c = Config::load(dir / "c.yaml", {"transport.slots=6", "log.level=debug"});
  EXPECT_EQ(c.getInt("transport.slots"), 6);
  EXPECT_EQ(c.getString("log.level"), "debug");
}

TEST(Config, UnknownKeyInFileIsAnErrorNamingTheKey) {
  rekon::test::TempDir dir;
  std::ofstream(dir / "c.yaml") << "transport:\n  slotz: 4\n";
  try {
    Config::load(dir / "c.yaml");
    FAIL() << "unknown key accepted";
  } catch (const rekon::Error& e) {
    EXPECT_NE(std::string(e.what()).find("transport.slotz"), std::string::npos) << e.what();
  }
}

TEST(Config, UnknownSetKeyAndMalformedSetAreErrors) {
  EXPECT_THROW(Config::load("", {"nope.key=1"}), rekon::Error);
  EXPECT_THROW(Config::load("", {"transport.slots"}), rekon::Error);
  EXPECT_THROW(Config::load("", {"transport=3"}), rekon::Error);
}

TEST(Config, InvalidYamlIsAnErrorNamingTheFile) {
  rekon::test::TempDir dir;
  std::ofstream(dir / "bad.yaml") << "transport: [unclosed\n";
  try {
    Config::load(dir / "bad.yaml");
    FAIL();
  } catch (const rekon::Error& e) {
    EXPECT_NE(std::string(e.what()).find("bad.yaml"), std::string::npos) << e.what();
  }
}

// Found by fuzz_config: a list as a key ended in std::terminate (an uncaught
// YAML conversion error) instead of a rekon::Error.
TEST(Config, AListOrMappingAsAKeyIsAnErrorNamingTheSection) {
  rekon::test::TempDir dir;
  std::ofstream(dir / "keys.yaml") << "tracker:\n  ? [finest_level, coarsest_level]\n  : 1\n";
  try {
    Config::load(dir / "keys.yaml");
    FAIL();
  } catch (const rekon::Error& e) {
    EXPECT_NE(std::string(e.what()).find("keys.yaml"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("'tracker'"), std::string::npos) << e.what();
  }
}

TEST(Config, WrongTypeIsAnErrorNamingTheKey) {
  const Config c = Config::load("", {"transport.slots=many"});
  EXPECT_THROW(c.getInt("transport.slots"), rekon::Error);
}

TEST(Config, DumpRoundTrips) {
  const Config a = Config::load("", {"transport.slots=5"});
  const Config b = Config::fromYamlText(a.dump());
  EXPECT_EQ(b.getInt("transport.slots"), 5);
}
