#pragma once

namespace rekon::frontend_check {

// `rekon frontend-check [--log FILE.lcm] [--ack-name NAME] [--done-service NAME]
// [--max-latency-ms MS] [--timeout S]`: judges a frontend against every rule
// of messages/FRONTEND.md, from the bus (until its done_t, then a short
// linger, or --timeout) or from an lcm-logger log. Prints one line per rule;
// exit 0 when every rule passes, 1 otherwise.
int frontendCheckCommand(int argc, char** argv);

}  // namespace rekon::frontend_check
