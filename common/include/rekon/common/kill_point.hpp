#pragma once
// Named points where a crash-only test kills a process with SIGKILL, as
// kill -9 from outside would, but at a moment no outside kill can hit on
// purpose (inside the keyframe store's allocator, for one). A process whose
// environment holds REKON_KILL_AT=NAME kills itself the first time it reaches
// killPoint(NAME); REKON_KILL_AT=NAME#N, the N-th time. Without the variable
// a kill point costs one getenv.
namespace rekon {

void killPoint(const char* name);

}  // namespace rekon
