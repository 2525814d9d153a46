// Command-line options of the farm's programs (CLI11): how a main parses its argv, the exit code
// of a command line it refuses, and checks of option values that CLI11 does not carry.
#pragma once

#include <CLI/CLI.hpp>
#include <cstdio>
#include <stdexcept>
#include <string>
#include <vector>

namespace farm::cli {

// The exit code of a command line a program refuses (unknown option, bad or missing value);
// scripts and tests check it.
inline constexpr int kUsageExit = 2;

// A program's options. A value given twice takes the last one, as the farm's scripts expect (a
// default early on the command line, then the caller's).
class App : public CLI::App {
 public:
  explicit App(const std::string& name) : CLI::App("", name) {
    option_defaults()->multi_option_policy(CLI::MultiOptionPolicy::TakeLast);
  }
};

// Parses argc/argv into app's options. Returns -1 when the program goes on, else the code it ends
// with: 0 after --help (printed on stdout), usage_exit after an error (printed on stderr with the
// option and the value at fault).
inline int parse(CLI::App& app, int argc, char** argv, int usage_exit = kUsageExit) {
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    // CLI11 checks for missing required options before it reports unknown ones; an unknown option
    // is the fault to name then (a typo in a required option's name makes both).
    const std::vector<std::string> unknown = app.remaining();
    if (dynamic_cast<const CLI::RequiredError*>(&e) && !unknown.empty()) {
      app.exit(CLI::ExtrasError(unknown));
      return usage_exit;
    }
    return app.exit(e) == 0 ? 0 : usage_exit;
  }
  return -1;
}

// A number strictly greater than lo (and at most hi): "Value X is not a number in (lo, hi]".
inline CLI::Validator above(double lo, double hi = 1e300) {
  char range[64];
  if (hi < 1e300)
    std::snprintf(range, sizeof range, "(%g, %g]", lo, hi);
  else
    std::snprintf(range, sizeof range, "> %g", lo);
  const std::string text = range;
  return CLI::Validator(
      [lo, hi, text](std::string& input) -> std::string {
        double v = 0;
        if (!CLI::detail::lexical_cast(input, v) || !(v > lo && v <= hi))
          return "Value " + input + " is not a number " + (text[0] == '(' ? "in " : "") + text;
        return {};
      },
      "NUMBER " + text);
}

// A number greater than 0.
inline CLI::Validator positive() { return above(0); }

// A number in [lo, hi], written with %g (CLI::Range writes doubles with six decimals).
inline CLI::Validator within(double lo, double hi) {
  char range[64];
  std::snprintf(range, sizeof range, "[%g, %g]", lo, hi);
  const std::string text = range;
  return CLI::Validator(
      [lo, hi, text](std::string& input) -> std::string {
        double v = 0;
        if (!CLI::detail::lexical_cast(input, v) || !(v >= lo && v <= hi))
          return "Value " + input + " is not a number in " + text;
        return {};
      },
      "NUMBER in " + text);
}

// A whole number of decimal digits (no sign): "Value X is not a whole number".
inline CLI::Validator whole_number() {
  return CLI::Validator(
      [](std::string& input) {
        const bool digits = !input.empty() && input.find_first_not_of("0123456789") == std::string::npos;
        return digits ? std::string() : "Value " + input + " is not a whole number";
      },
      "WHOLE");
}

// A text that must not be empty: "Value is empty: needs WHAT".
inline CLI::Validator non_empty(const std::string& what) {
  return CLI::Validator(
      [what](std::string& input) { return input.empty() ? "Value is empty: needs " + what : std::string(); },
      "NON-EMPTY");
}

// A check by a function that throws std::invalid_argument naming the fault; with ->transform, what
// it returns replaces the value.
template <typename F>
CLI::Validator checked_by(F f, const std::string& name) {
  return CLI::Validator(
      [f](std::string& input) -> std::string {
        try {
          input = f(input);
        } catch (const std::invalid_argument& e) {
          return e.what();
        }
        return {};
      },
      name);
}

}  // namespace farm::cli
