#pragma once
// Command-line parsing shared by every rekon binary and subcommand:
// `--name value`, `--flag`, repeated options, positionals, and `--help`.
#include <map>
#include <optional>
#include <string>
#include <vector>

namespace rekon {

class ArgParser {
 public:
  ArgParser(std::string program, std::string summary);

  // An option that takes a value; `fallback` is shown in --help.
  ArgParser& option(const std::string& name, const std::string& help, const std::string& fallback = "");
  // An option that may be given several times (e.g. --set key=value).
  ArgParser& repeated(const std::string& name, const std::string& help);
  ArgParser& flag(const std::string& name, const std::string& help);
  ArgParser& positional(const std::string& name, const std::string& help);
  // Example command lines, one a line, shown at the end of --help.
  ArgParser& examples(std::string lines);

  // Returns false when --help was printed (the caller exits 0). Throws
  // rekon::Error for an unknown option, a missing value or a missing positional.
  bool parse(int argc, char** argv);

  bool has(const std::string& name) const;
  std::string get(const std::string& name) const;  // value or its fallback
  double getDouble(const std::string& name) const;
  int getInt(const std::string& name) const;
  bool flagSet(const std::string& name) const;
  const std::vector<std::string>& all(const std::string& name) const;
  std::string usage() const;

 private:
  struct Spec {
    std::string help, fallback;
    bool takes_value = true, repeated = false;
  };
  std::string program_, summary_, examples_;
  std::map<std::string, Spec> specs_;
  std::vector<std::string> option_order_;
  std::vector<std::pair<std::string, std::string>> positionals_;
  std::map<std::string, std::vector<std::string>> values_;
};

// The candidate nearest to `word` by edit distance (a swap of two neighbours
// counts one), if it is close enough to be a typo of it (at most 2 edits, or a
// third of the word's length); nullopt otherwise. For "did you mean ...?".
std::optional<std::string> nearestName(const std::string& word, const std::vector<std::string>& candidates);

// "; did you mean 'NAME'?" for the nearest candidate, or "" when none is near.
std::string didYouMean(const std::string& word, const std::vector<std::string>& candidates);

// Creates an output folder (--out) and its parents; a rekon::Error naming the
// folder and the reason (permission, a file in the way) when it cannot.
void createOutputFolder(const std::string& dir);

}  // namespace rekon
