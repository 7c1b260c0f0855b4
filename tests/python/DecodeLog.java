// Decodes every event of an lcm-logger log as lcm-spy does: the type found by the message's fingerprint among the
// LCM types on the class path (lcm.spy.LCMTypeDatabase, lcm-spy's own lookup), then built by its DataInput
// constructor. Channels that do not start with PREFIX (LCM's own LCM_SELF_TEST) are counted and skipped. One line per
// channel (events, decoded, the type), a last line with the totals; exit 1 when an event fails to decode or the log
// holds none.
//   java -cp lcm.jar:rekon_msgs.jar:. DecodeLog run.lcm REKON_
import java.io.ByteArrayInputStream;
import java.io.DataInput;
import java.io.DataInputStream;
import java.io.EOFException;
import java.util.Map;
import java.util.TreeMap;

public class DecodeLog {
  public static void main(String[] args) throws Exception {
    lcm.spy.LCMTypeDatabase types = new lcm.spy.LCMTypeDatabase();
    lcm.logging.Log log = new lcm.logging.Log(args[0], "r");
    Map<String, long[]> counts = new TreeMap<>();  // events, decoded
    Map<String, String> typeOf = new TreeMap<>();
    String prefix = args.length > 1 ? args[1] : "";
    long events = 0, failed = 0, skipped = 0;
    while (true) {
      lcm.logging.Log.Event e;
      try {
        e = log.readNext();
      } catch (EOFException end) {
        break;
      }
      if (!e.channel.startsWith(prefix)) {
        ++skipped;
        continue;
      }
      ++events;
      long[] c = counts.computeIfAbsent(e.channel, k -> new long[2]);
      ++c[0];
      try {
        long fingerprint = new DataInputStream(new ByteArrayInputStream(e.data)).readLong();
        Class<?> cls = types.getClassByFingerprint(fingerprint);
        if (cls == null) throw new Exception("no type on the class path has fingerprint " + Long.toHexString(fingerprint));
        cls.getConstructor(DataInput.class).newInstance(new DataInputStream(new ByteArrayInputStream(e.data)));
        ++c[1];
        typeOf.put(e.channel, cls.getName());
      } catch (Exception ex) {
        if (failed++ < 10) System.out.println("FAIL " + e.channel + " event " + e.eventNumber + ": " + ex);
      }
    }
    for (Map.Entry<String, long[]> c : counts.entrySet()) {
      System.out.println(c.getKey() + " events " + c.getValue()[0] + " decoded " + c.getValue()[1] + " type "
                         + typeOf.getOrDefault(c.getKey(), "none"));
    }
    System.out.println("total events " + events + " decoded " + (events - failed) + " failed " + failed + " (skipped "
                       + skipped + " on channels without the prefix " + prefix + ")");
    System.exit(failed == 0 && events > 0 ? 0 : 1);
  }
}
