// error.h — the one exception type for bad user input.
//
// Contract: anything a user can get wrong (a scene file, a USD attribute, a setting)
// is reported as InputError whose message names the object and the attribute, e.g.
//   /World/Sand.packingRate: 0.9 is outside (0, 0.64]
// Front ends print the message and exit with status 2; nothing ever crashes or
// renders NaN because of input.
#pragma once

#include <cstdio>
#include <sstream>
#include <stdexcept>
#include <string>

namespace granular {

class InputError : public std::runtime_error {
 public:
  InputError(const std::string& object, const std::string& attribute, const std::string& what)
      : std::runtime_error(object + (attribute.empty() ? "" : "." + attribute) + ": " + what),
        object_(object), attribute_(attribute), detail_(what) {}
  const std::string& object() const { return object_; }
  const std::string& attribute() const { return attribute_; }
  const std::string& detail() const { return detail_; }  // the message without "object.attribute: "

 private:
  std::string object_, attribute_, detail_;
};

// A command-line tool's body, with the project's exit statuses: an InputError is the
// user's (one "error: object.attribute: ..." line, status 2), any other exception a failure
// (status 1).
template <typename Body>
int runTool(Body&& body) {
  try {
    return body();
  } catch (const InputError& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return 2;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return 1;
  }
}

template <typename... Ts>
std::string str(const Ts&... parts) {
  std::ostringstream s;
  (s << ... << parts);
  return s.str();
}

// A token read from a file, as an error quotes it: its first `max` bytes, each that is not
// printable ASCII as '?' (a file may hold any bytes; a front end decodes messages as UTF-8).
inline std::string printableToken(const std::string& token, size_t max = 40) {
  std::string s = token.substr(0, max);
  for (char& c : s)
    if (c < 0x20 || c > 0x7e) c = '?';
  return s;
}

}  // namespace granular
